use core::ops::{Add, AddAssign, Div, Index, Mul, Neg, Sub, SubAssign};

/// A 2-vector of f32.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Vec2 {
    /// First component.
    pub x: f32,
    /// Second component.
    pub y: f32,
}

/// A 3-vector of f32.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Vec3 {
    /// First component.
    pub x: f32,
    /// Second component.
    pub y: f32,
    /// Third component.
    pub z: f32,
}

impl Vec2 {
    /// The zero vector.
    pub const ZERO: Vec2 = Vec2 { x: 0.0, y: 0.0 };

    /// Builds a vector.
    pub const fn new(x: f32, y: f32) -> Self {
        Self { x, y }
    }
    /// Dot product.
    pub fn dot(self, o: Self) -> f32 {
        self.x * o.x + self.y * o.y
    }
    /// 2-D cross product (z of the 3-D cross product).
    pub fn cross(self, o: Self) -> f32 {
        self.x * o.y - self.y * o.x
    }
    /// Euclidean norm.
    pub fn norm(self) -> f32 {
        libm::sqrtf(self.dot(self))
    }
    /// The vector rotated by +90 degrees.
    pub fn perp(self) -> Self {
        Self::new(-self.y, self.x)
    }
    /// Unit vector, or `None` for a (near) zero vector.
    pub fn normalized(self) -> Option<Self> {
        let n = self.norm();
        if n > 1e-30 && n.is_finite() { Some(self * (1.0 / n)) } else { None }
    }
    /// As an array.
    pub fn to_array(self) -> [f32; 2] {
        [self.x, self.y]
    }
}

impl Vec3 {
    /// The zero vector.
    pub const ZERO: Vec3 = Vec3 { x: 0.0, y: 0.0, z: 0.0 };
    /// Unit x.
    pub const X: Vec3 = Vec3 { x: 1.0, y: 0.0, z: 0.0 };
    /// Unit y.
    pub const Y: Vec3 = Vec3 { x: 0.0, y: 1.0, z: 0.0 };
    /// Unit z.
    pub const Z: Vec3 = Vec3 { x: 0.0, y: 0.0, z: 1.0 };

    /// Builds a vector.
    pub const fn new(x: f32, y: f32, z: f32) -> Self {
        Self { x, y, z }
    }
    /// From an array.
    pub const fn from_array(a: [f32; 3]) -> Self {
        Self { x: a[0], y: a[1], z: a[2] }
    }
    /// As an array.
    pub const fn to_array(self) -> [f32; 3] {
        [self.x, self.y, self.z]
    }
    /// Dot product.
    pub fn dot(self, o: Self) -> f32 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    /// Cross product.
    pub fn cross(self, o: Self) -> Self {
        Self::new(self.y * o.z - self.z * o.y, self.z * o.x - self.x * o.z, self.x * o.y - self.y * o.x)
    }
    /// Squared norm.
    pub fn norm_sq(self) -> f32 {
        self.dot(self)
    }
    /// Euclidean norm.
    pub fn norm(self) -> f32 {
        libm::sqrtf(self.norm_sq())
    }
    /// Unit vector, or `None` for a (near) zero or non-finite vector.
    pub fn normalized(self) -> Option<Self> {
        let n = self.norm();
        if n > 1e-30 && n.is_finite() { Some(self * (1.0 / n)) } else { None }
    }
    /// Component-wise product.
    pub fn hadamard(self, o: Self) -> Self {
        Self::new(self.x * o.x, self.y * o.y, self.z * o.z)
    }
    /// True when all components are finite.
    pub fn is_finite(self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.z.is_finite()
    }
    /// The first two components.
    pub fn xy(self) -> Vec2 {
        Vec2::new(self.x, self.y)
    }
}

impl Index<usize> for Vec3 {
    type Output = f32;
    fn index(&self, i: usize) -> &f32 {
        match i {
            0 => &self.x,
            1 => &self.y,
            _ => &self.z,
        }
    }
}

macro_rules! vec_ops {
    ($t:ident, $($f:ident),+) => {
        impl Add for $t {
            type Output = $t;
            fn add(self, o: $t) -> $t { $t { $($f: self.$f + o.$f),+ } }
        }
        impl Sub for $t {
            type Output = $t;
            fn sub(self, o: $t) -> $t { $t { $($f: self.$f - o.$f),+ } }
        }
        impl Neg for $t {
            type Output = $t;
            fn neg(self) -> $t { $t { $($f: -self.$f),+ } }
        }
        impl Mul<f32> for $t {
            type Output = $t;
            fn mul(self, s: f32) -> $t { $t { $($f: self.$f * s),+ } }
        }
        impl Mul<$t> for f32 {
            type Output = $t;
            fn mul(self, v: $t) -> $t { $t { $($f: self * v.$f),+ } }
        }
        impl Div<f32> for $t {
            type Output = $t;
            fn div(self, s: f32) -> $t { $t { $($f: self.$f / s),+ } }
        }
        impl AddAssign for $t {
            fn add_assign(&mut self, o: $t) { $(self.$f += o.$f;)+ }
        }
        impl SubAssign for $t {
            fn sub_assign(&mut self, o: $t) { $(self.$f -= o.$f;)+ }
        }
    };
}
vec_ops!(Vec2, x, y);
vec_ops!(Vec3, x, y, z);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cross_is_right_handed() {
        assert_eq!(Vec3::X.cross(Vec3::Y), Vec3::Z);
        assert_eq!(Vec3::Y.cross(Vec3::Z), Vec3::X);
        assert_eq!(Vec2::new(1.0, 0.0).cross(Vec2::new(0.0, 1.0)), 1.0);
    }

    #[test]
    fn normalized_rejects_zero() {
        assert!(Vec3::ZERO.normalized().is_none());
        assert!(Vec3::new(f32::NAN, 0.0, 0.0).normalized().is_none());
        let n = Vec3::new(3.0, 0.0, 4.0).normalized();
        assert_eq!(n, Some(Vec3::new(0.6, 0.0, 0.8)));
    }
}
