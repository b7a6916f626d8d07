//! One declaration per parameter: `params_struct!` declares a parameter structure field by field (doc, type,
//! default, range, unit) and generates from it the structure, its `Default`, the range checks of
//! validation ([`ParamError`] naming the dotted field) and the [`ParamSpec`] table that `sim-host params`
//! prints as docs/parameters.md. Checks that relate several fields (Routh-Hurwitz, one bound below another)
//! stay written out in the structure's `validate`, after the declared ranges.
//!
//! The model is PX4's parameter YAML (a name, a type, a default, `min`/`max`, a unit and a description per
//! parameter, from which the firmware's tables and the documentation are generated); written as a
//! `macro_rules!` table here because the firmware is `no_std` without a build-time generator.
use crate::params::ParamError;

/// A declared range: each bound closed or open.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Range {
    /// Lower bound.
    pub lo: f32,
    /// Whether the lower bound itself is excluded.
    pub lo_open: bool,
    /// Upper bound (`f32::INFINITY` for none).
    pub hi: f32,
    /// Whether the upper bound itself is excluded.
    pub hi_open: bool,
}

impl Range {
    /// Whether `v` is finite and within the range.
    pub fn contains(&self, v: f32) -> bool {
        let above = if self.lo_open { v > self.lo } else { v >= self.lo };
        let below = if self.hi_open { v < self.hi } else { v <= self.hi };
        v.is_finite() && above && below
    }
}

/// One declared parameter, as docs/parameters.md lists it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParamSpec {
    /// Dotted name, as in scenario files (`vehicle.mass_kg`).
    pub name: &'static str,
    /// Rust type (`f32`, `[f32; 3]`, `u8`, `bool`, or a section's structure).
    pub ty: &'static str,
    /// Unit (empty for counts and ratios).
    pub unit: &'static str,
    /// The field's documentation.
    pub doc: &'static str,
    /// The declared range (`None`: a section, a switch, or a value checked only against other fields).
    pub range: Option<Range>,
    /// The range as the refusal states it (`must lie in [0.05, 20] kg`), empty without a range.
    pub problem: &'static str,
    /// Whether the entry is a section (a nested structure), not a value.
    pub section: bool,
}

/// What validation needs of a declared parameter (the firmware links these, not the documentation of
/// [`ParamSpec`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Check {
    /// Dotted name.
    pub name: &'static str,
    /// The declared range, if any.
    pub range: Option<Range>,
    /// The range as the refusal states it.
    pub problem: &'static str,
}

/// A value a declared range can check: a number, or each element of an array of numbers.
pub trait Ranged {
    /// Whether every number in `self` lies in `r`.
    fn within(&self, r: &Range) -> bool;
}

impl Ranged for f32 {
    fn within(&self, r: &Range) -> bool {
        r.contains(*self)
    }
}

impl Ranged for u8 {
    fn within(&self, r: &Range) -> bool {
        r.contains(*self as f32)
    }
}

impl<const N: usize> Ranged for [f32; N] {
    fn within(&self, r: &Range) -> bool {
        self.iter().all(|v| r.contains(*v))
    }
}

impl<const N: usize> Ranged for [u8; N] {
    fn within(&self, r: &Range) -> bool {
        self.iter().all(|v| r.contains(*v as f32))
    }
}

/// Checks one declared value: the error names the field and states the range.
pub fn check_declared<T: Ranged>(v: &T, spec: &Check) -> Result<(), ParamError> {
    match &spec.range {
        Some(r) if !v.within(r) => Err(ParamError { field: spec.name, problem: spec.problem }),
        _ => Ok(()),
    }
}

/// Declares a parameter structure; see the module's documentation. Each field is
///
/// ```text
/// /// Its documentation.
/// name: type = default, { >= lo, <= hi } "unit";    // or > / < for open bounds, or one bound alone
/// name: type = default, { any } "";                 // a switch, or checked only against other fields
/// name: type = default, { section } "";             // a nested parameter structure
/// ```
///
/// and the structure names where it sits in the parameter tree (`in ["vehicle"]`; a structure used twice,
/// such as the roll and pitch gains, lists both places; the root of the tree is `in [""]`).
macro_rules! params_struct {
    (
        $(#[$meta:meta])*
        pub struct $name:ident in [$($prefix:tt),+ $(,)?] $body:tt
    ) => {
        params_struct!(@struct [$(#[$meta])*] $name $body);
        impl $name {
            /// The declared parameters of this structure, one table per place it sits in the tree.
            pub const SPECS: &'static [&'static [$crate::declare::ParamSpec]] =
                &[$(params_struct!(@specs $prefix $body)),+];

            /// What validation checks of [`Self::SPECS`] (without the documentation).
            const CHECKS: &'static [&'static [$crate::declare::Check]] = &[$(params_struct!(@checks $prefix $body)),+];

            /// The declared ranges of the structure at place `instance` of [`Self::SPECS`] (sections are
            /// checked by their own structure).
            #[allow(unused_assignments)]
            fn check_declared(&self, instance: usize) -> Result<(), $crate::params::ParamError> {
                params_struct!(@check self Self::CHECKS[instance], $body);
                Ok(())
            }
        }
    };
    (@struct [$(#[$meta:meta])*] $name:ident {
        $( $(#[doc = $doc:literal])* $field:ident : $ty:ty = $default:expr, $kind:tt $unit:literal; )*
    }) => {
        $(#[$meta])*
        pub struct $name {
            $( $(#[doc = $doc])* pub $field: $ty, )*
        }
        impl Default for $name {
            fn default() -> Self {
                Self { $( $field: $default, )* }
            }
        }
    };
    (@specs $prefix:tt {
        $( $(#[doc = $doc:literal])* $field:ident : $ty:ty = $default:expr, $kind:tt $unit:literal; )*
    }) => {
        &[$(
            $crate::declare::ParamSpec {
                name: params_struct!(@name $prefix $field),
                ty: stringify!($ty),
                unit: $unit,
                doc: concat!($($doc),*),
                range: params_struct!(@range $kind),
                problem: params_struct!(@problem $kind $unit),
                section: params_struct!(@is_section $kind),
            }
        ),*]
    };
    (@checks $prefix:tt {
        $( $(#[doc = $doc:literal])* $field:ident : $ty:ty = $default:expr, $kind:tt $unit:literal; )*
    }) => {
        &[$(
            $crate::declare::Check {
                name: params_struct!(@name $prefix $field),
                range: params_struct!(@range $kind),
                problem: params_struct!(@problem $kind $unit),
            }
        ),*]
    };
    // The root of the tree (`in [""]`) names its fields without a prefix.
    (@name "" $field:ident) => { stringify!($field) };
    (@name $prefix:literal $field:ident) => { concat!($prefix, ".", stringify!($field)) };
    (@check $self:ident $specs:expr, {
        $( $(#[doc = $doc:literal])* $field:ident : $ty:ty = $default:expr, $kind:tt $unit:literal; )*
    }) => {
        let specs: &[$crate::declare::Check] = $specs;
        let mut i = 0;
        $(
            params_struct!(@check_one $kind $self.$field, &specs[i]);
            i += 1;
        )*
    };
    (@check_one { any } $v:expr, $spec:expr) => {};
    (@check_one { section } $v:expr, $spec:expr) => {};
    (@check_one $kind:tt $v:expr, $spec:expr) => {
        $crate::declare::check_declared(&$v, $spec)?
    };
    (@is_section { section }) => { true };
    (@is_section $kind:tt) => { false };
    (@range { any }) => { None };
    (@range { section }) => { None };
    (@range { $lo_op:tt $lo:expr, $hi_op:tt $hi:expr }) => {
        Some($crate::declare::Range {
            lo: $lo as f32,
            lo_open: params_struct!(@open $lo_op),
            hi: $hi as f32,
            hi_open: params_struct!(@open $hi_op),
        })
    };
    (@range { $lo_op:tt $lo:expr }) => {
        Some($crate::declare::Range {
            lo: $lo as f32,
            lo_open: params_struct!(@open $lo_op),
            hi: f32::INFINITY,
            hi_open: true,
        })
    };
    (@problem { any } $unit:literal) => { "" };
    (@problem { section } $unit:literal) => { "" };
    (@problem { $lo_op:tt $lo:expr, $hi_op:tt $hi:expr } $unit:literal) => {
        concat!(
            "must lie in ",
            params_struct!(@bracket $lo_op),
            stringify!($lo),
            ", ",
            stringify!($hi),
            params_struct!(@bracket $hi_op),
            " ",
            $unit
        )
    };
    (@problem { $lo_op:tt $lo:expr } $unit:literal) => {
        concat!("must be finite and ", stringify!($lo_op), " ", stringify!($lo), " ", $unit)
    };
    (@open >) => { true };
    (@open >=) => { false };
    (@open <) => { true };
    (@open <=) => { false };
    (@bracket >) => { "(" };
    (@bracket >=) => { "[" };
    (@bracket <) => { ")" };
    (@bracket <=) => { "]" };
}
