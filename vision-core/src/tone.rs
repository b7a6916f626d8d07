//! A camera's tone curve: how the light a pixel integrates becomes its 8-bit value.
//!
//! Sensors integrate linear light, and cameras (webcams included) deliver sRGB-encoded values
//! (IEC 61966-2-1: a linear segment of slope 12.92 below 0.0031308, then `1.055 x^(1/2.4) - 0.055`). The
//! detector's sub-pixel edges (the area method, [`crate::detect`]) assume pixel values linear in the painted
//! fraction of the pixel; on sRGB values the band read 0.25 px too thin and the pose lost centimetres
//! (docs/camera-effects.md). The detector therefore maps each channel back to linear light first, with the curve of
//! the camera's calibration ([`ToneCurve::Srgb`] unless the calibration says otherwise).

/// The camera's response from linear light to the delivered 8-bit values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ToneCurve {
    /// Values proportional to the light (raw sensor data, machine-vision cameras with gamma 1).
    Linear,
    /// The sRGB transfer function, as webcams and most cameras deliver.
    #[default]
    Srgb,
}

impl ToneCurve {
    /// Linear light (0..1, clipped) of an encoded value (0..1).
    pub fn decode(self, v: f32) -> f32 {
        let v = v.clamp(0.0, 1.0);
        match self {
            ToneCurve::Linear => v,
            ToneCurve::Srgb => {
                if v <= 0.040_45 {
                    v / 12.92
                } else {
                    libm::powf((v + 0.055) / 1.055, 2.4)
                }
            }
        }
    }

    /// Encoded value (0..1) of linear light (clipped to 0..1 first: the sensor saturates).
    pub fn encode(self, x: f32) -> f32 {
        let x = if x > 0.0 { x.min(1.0) } else { 0.0 };
        match self {
            ToneCurve::Linear => x,
            ToneCurve::Srgb => {
                if x <= 0.003_130_8 {
                    12.92 * x
                } else {
                    1.055 * libm::powf(x, 1.0 / 2.4) - 0.055
                }
            }
        }
    }
}

/// Linear light per 8-bit value, in units of 1/16 grey level (0..4080): a [`ToneCurve::Linear`] table is
/// `16 v`, so integer arithmetic on it scales the 8-bit signal by exactly 16.
pub const LINEAR_SCALE: i32 = 16;

/// The lookup table from 8-bit values to linear light (`LINEAR_SCALE` units per grey level).
pub fn linear_table(curve: ToneCurve) -> [u16; 256] {
    let mut t = [0u16; 256];
    for (v, o) in t.iter_mut().enumerate() {
        let x = curve.decode(v as f32 / 255.0) * (255 * LINEAR_SCALE) as f32;
        *o = (x + 0.5) as u16;
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_matches_the_standard_and_round_trips() {
        // IEC 61966-2-1 reference points: 0.5 linear encodes to 0.7354, 0.2140 linear is 0.5 encoded, and
        // the linear segment's end.
        let s = ToneCurve::Srgb;
        assert!((s.encode(0.5) - 0.735_36).abs() < 1e-4, "{}", s.encode(0.5));
        assert!((s.decode(0.5) - 0.214_04).abs() < 1e-4, "{}", s.decode(0.5));
        assert!((s.encode(0.002) - 0.025_84).abs() < 1e-5);
        assert_eq!((s.encode(0.0), s.encode(-1.0)), (0.0, 0.0));
        assert!((s.encode(1.0) - 1.0).abs() < 1e-6 && s.encode(3.0) == s.encode(1.0), "clipped at 1");
        for k in 0..=100 {
            let x = k as f32 / 100.0;
            assert!((s.decode(s.encode(x)) - x).abs() < 1e-5, "{x}");
            assert_eq!(ToneCurve::Linear.encode(x), x);
            assert_eq!(ToneCurve::Linear.decode(x), x);
        }
    }

    #[test]
    fn tables_are_exact_for_linear_and_monotonic_for_srgb() {
        let lin = linear_table(ToneCurve::Linear);
        let srgb = linear_table(ToneCurve::Srgb);
        for v in 0..256 {
            assert_eq!(lin[v] as i32, LINEAR_SCALE * v as i32);
        }
        assert_eq!((srgb[0], srgb[255]), (0, 4080));
        assert!(srgb.windows(2).all(|w| w[1] > w[0]), "strictly increasing");
        // Mid grey 128 is 21.6 % of the light.
        assert_eq!(srgb[128], (0.215_861 * 4080.0f32).round() as u16);
    }
}
