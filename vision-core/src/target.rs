//! The painted line: a rectangle on the wall plane `y = 0`, in world coordinates.
use geometry::Vec3;

/// A corner of the line's rectangle, named as in the paper's Fig. 1 (`a, b, c, d` in the image).
///
/// `A` and `B` are the `x = x_start` end (bottom and top), `C` and `D` the `x = x_end` end (top and bottom), so
/// `AB` and `CD` are the short edges (the paper's `m1`, `m2`) and `BC`, `DA` the long ones (`l1`, `l2`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Corner {
    /// `(x_start, z_bottom)`.
    A = 0,
    /// `(x_start, z_top)`.
    B = 1,
    /// `(x_end, z_top)`.
    C = 2,
    /// `(x_end, z_bottom)`.
    D = 3,
}

impl Corner {
    /// All corners in order.
    pub const ALL: [Corner; 4] = [Corner::A, Corner::B, Corner::C, Corner::D];
}

/// An edge of the line's rectangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Edge {
    /// The upper long edge, `B -> C`.
    Top = 0,
    /// The lower long edge, `A -> D`.
    Bottom = 1,
    /// The short edge at `x = x_start`, `A -> B`.
    StartEnd = 2,
    /// The short edge at `x = x_end`, `D -> C`.
    FinishEnd = 3,
}

impl Edge {
    /// All edges in order.
    pub const ALL: [Edge; 4] = [Edge::Top, Edge::Bottom, Edge::StartEnd, Edge::FinishEnd];
}

/// Geometry of the painted line (metres, world frame). The paper's line is 2.30 m long; its height on the
/// wall and its thickness are the project's defaults ([`LineTarget::PAPER`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LineTarget {
    /// World x of the start end (m).
    pub x_start_m: f32,
    /// World x of the finish end (m), greater than `x_start_m`.
    pub x_end_m: f32,
    /// Height of the lower edge above the floor (m).
    pub z_bottom_m: f32,
    /// Height of the upper edge above the floor (m).
    pub z_top_m: f32,
}

impl LineTarget {
    /// 2.30 m long, 0.10 m high, lower edge 0.95 m above the floor, ends at x = 0 and x = 2.30 m.
    pub const PAPER: LineTarget =
        LineTarget { x_start_m: 0.0, x_end_m: 2.30, z_bottom_m: 0.95, z_top_m: 1.05 };

    /// The corner's world position.
    pub fn corner(&self, c: Corner) -> Vec3 {
        match c {
            Corner::A => Vec3::new(self.x_start_m, 0.0, self.z_bottom_m),
            Corner::B => Vec3::new(self.x_start_m, 0.0, self.z_top_m),
            Corner::C => Vec3::new(self.x_end_m, 0.0, self.z_top_m),
            Corner::D => Vec3::new(self.x_end_m, 0.0, self.z_bottom_m),
        }
    }

    /// The edge's two end corners, in the direction the edge is named.
    pub fn edge_corners(&self, e: Edge) -> (Corner, Corner) {
        match e {
            Edge::Top => (Corner::B, Corner::C),
            Edge::Bottom => (Corner::A, Corner::D),
            Edge::StartEnd => (Corner::A, Corner::B),
            Edge::FinishEnd => (Corner::D, Corner::C),
        }
    }

    /// The edge's end points in world coordinates.
    pub fn edge_points(&self, e: Edge) -> (Vec3, Vec3) {
        let (a, b) = self.edge_corners(e);
        (self.corner(a), self.corner(b))
    }

    /// Centre of the rectangle.
    pub fn center(&self) -> Vec3 {
        Vec3::new(0.5 * (self.x_start_m + self.x_end_m), 0.0, 0.5 * (self.z_bottom_m + self.z_top_m))
    }

    /// Length along x (m).
    pub fn length_m(&self) -> f32 {
        self.x_end_m - self.x_start_m
    }

    /// Height along z (m).
    pub fn height_m(&self) -> f32 {
        self.z_top_m - self.z_bottom_m
    }

    /// True when the dimensions are finite and positive.
    pub fn is_valid(&self) -> bool {
        self.length_m() > 0.0
            && self.height_m() > 0.0
            && self.length_m().is_finite()
            && self.height_m().is_finite()
    }
}
