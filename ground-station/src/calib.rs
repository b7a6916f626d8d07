//! Camera calibration files in the formats users have:
//!
//! - OpenCV / ROS `camera_info` YAML (what `camera_calibration`'s `cameracalibrator.py` and OpenCV's
//!   calibration samples write): `image_width`, `image_height`, `camera_matrix` (`data` row-major 3x3),
//!   `distortion_model: plumb_bob` (or `rational_polynomial` with its higher terms zero) and
//!   `distortion_coefficients` (`data`: k1, k2, p1, p2, k3);
//! - Kalibr / EuRoC `sensor.yaml` and Kalibr's `camchain.yaml` (its first camera, `cam0`):
//!   `resolution: [w, h]`, `camera_model: pinhole`, `intrinsics: [fu, fv, cu, cv]`,
//!   `distortion_model: radial-tangential` (or `radtan`, `none`) and `distortion_coefficients` (or
//!   `distortion_coeffs`): k1, k2, p1, p2.
//!
//! The result is a [`CameraModel`] with OpenCV's Brown-Conrady distortion, which the line detector and the
//! flow undistort their points with. Every refusal names the file and the field; a calibration of another
//! size than the stream's is refused with both sizes ([`check_size`]).
use std::path::Path;
use vision_core::{CameraModel, Distortion, ToneCurve};
use yaml_rust2::{Yaml, YamlLoader};

/// Which format a file was read as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CalibFormat {
    /// OpenCV / ROS `camera_info`.
    CameraInfo,
    /// Kalibr / EuRoC `sensor.yaml`, or a camera of a Kalibr camchain.
    Kalibr,
}

/// A camera's calibration as read from a file.
#[derive(Clone, Debug, PartialEq)]
pub struct Calibration {
    /// The intrinsics and distortion, as the vision uses them (f32).
    pub camera: CameraModel,
    /// The file's intrinsics at full precision: fx, fy, cx, cy (px).
    pub intrinsics_px: [f64; 4],
    /// The file's distortion at full precision: k1, k2, p1, p2, k3.
    pub distortion: [f64; 5],
    /// The frame rate the file gives (Kalibr's `rate_hz`), if any.
    pub rate_hz: Option<f64>,
    /// The format it was read as.
    pub format: CalibFormat,
    /// The camera's tone curve: the optional key `tone_curve` (`srgb` or `linear`; neither format has one,
    /// and webcams deliver sRGB, the default).
    pub tone_curve: ToneCurve,
    /// A rolling shutter's delay between consecutive rows (s): the optional key `line_delay_s` (0, a global
    /// shutter, when absent). The station corrects the rows with the vehicle's rates when it is not zero.
    pub line_delay_s: f64,
}

/// Reads a calibration file (the format is recognised from its keys).
pub fn load(path: &Path) -> Result<Calibration, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    parse(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// Parses a calibration (the format is recognised from its keys).
pub fn parse(text: &str) -> Result<Calibration, String> {
    let docs = YamlLoader::load_from_str(text).map_err(|e| format!("not YAML: {e}"))?;
    let doc = docs.first().ok_or("an empty file")?;
    if doc.as_hash().is_none() {
        return Err("not a calibration: a mapping of keys expected".into());
    }
    if !doc["camera_matrix"].is_badvalue() || !doc["image_width"].is_badvalue() {
        return camera_info(doc);
    }
    if !doc["intrinsics"].is_badvalue() {
        return kalibr(doc, "");
    }
    // A Kalibr camchain: cam0, cam1, ... each a camera; the first one.
    if let Some(h) = doc.as_hash() {
        let mut cams: Vec<&str> =
            h.keys().filter_map(|k| k.as_str()).filter(|k| k.starts_with("cam")).collect();
        cams.sort();
        if let Some(first) = cams.first() {
            return kalibr(&doc[*first], &format!("{first}."));
        }
    }
    Err("neither a camera_info (`camera_matrix`, `image_width`) nor a Kalibr calibration (`intrinsics`, \
         `resolution`)"
        .into())
}

/// Refuses a calibration made for another image size than the stream's.
pub fn check_size(camera: &CameraModel, width: usize, height: usize) -> Result<(), String> {
    if (camera.width as usize, camera.height as usize) == (width, height) {
        Ok(())
    } else {
        Err(format!(
            "the calibration is for {}x{} images but the camera gives {width}x{height}: calibrate at the \
             stream's resolution (intrinsics do not scale with a crop)",
            camera.width, camera.height
        ))
    }
}

fn number(y: &Yaml, field: &str) -> Result<f64, String> {
    match y {
        Yaml::Integer(i) => Ok(*i as f64),
        Yaml::Real(_) => y.as_f64().ok_or_else(|| format!("`{field}` is not a number")),
        Yaml::BadValue => Err(format!("`{field}` is missing")),
        other => Err(format!("`{field}` is not a number ({other:?})")),
    }
}

fn list(y: &Yaml, field: &str) -> Result<Vec<f64>, String> {
    let v = match y {
        Yaml::Array(v) => v,
        Yaml::BadValue => return Err(format!("`{field}` is missing")),
        _ => return Err(format!("`{field}` is not a list")),
    };
    v.iter().enumerate().map(|(i, e)| number(e, &format!("{field}[{i}]"))).collect()
}

fn size(w: f64, h: f64, field: &str) -> Result<(u16, u16), String> {
    let ok = |v: f64| v.fract() == 0.0 && (1.0..=16384.0).contains(&v);
    if ok(w) && ok(h) {
        Ok((w as u16, h as u16))
    } else {
        Err(format!("`{field}`: {w}x{h} is not an image size (whole pixels, 1 to 16384)"))
    }
}

fn distortion(model: &str, d: &[f64], field: &str) -> Result<Distortion, String> {
    let model_l = model.to_ascii_lowercase();
    let get = |i: usize| d.get(i).copied().unwrap_or(0.0) as f32;
    match model_l.as_str() {
        "none" | "" if d.iter().all(|v| *v == 0.0) => Ok(Distortion::default()),
        "plumb_bob" | "radial-tangential" | "radtan" | "rational_polynomial" => {
            if d.len() < 4 {
                return Err(format!("`{field}`: {} coefficients; k1, k2, p1, p2 (and k3) expected", d.len()));
            }
            if d.iter().skip(5).any(|v| *v != 0.0) {
                return Err(format!(
                    "`{field}`: the rational model's k4-k6 are not supported (only k1, k2, p1, p2, k3); \
                     calibrate with plumb_bob"
                ));
            }
            if d.iter().any(|v| !v.is_finite()) {
                return Err(format!("`{field}`: a coefficient is not finite"));
            }
            Ok(Distortion { k1: get(0), k2: get(1), p1: get(2), p2: get(3), k3: get(4) })
        }
        _ => Err(format!(
            "distortion model `{model}` is not supported (plumb_bob, radial-tangential/radtan or none; \
             equidistant/fisheye lenses are not)"
        )),
    }
}

/// The calibration of either format: the camera checked, the file's values kept at full precision.
fn calibration(
    (width, height): (u16, u16),
    [fx, fy, cx, cy]: [f64; 4],
    distortion: Distortion,
    coefficients: &[f64],
    rate_hz: Option<f64>,
    format: CalibFormat,
    (tone_curve, line_delay_s): (ToneCurve, f64),
) -> Result<Calibration, String> {
    let camera = checked(CameraModel {
        width,
        height,
        fx: fx as f32,
        fy: fy as f32,
        cx: cx as f32,
        cy: cy as f32,
        distortion,
    })?;
    Ok(Calibration {
        camera,
        intrinsics_px: [fx, fy, cx, cy],
        distortion: [0, 1, 2, 3, 4].map(|i| coefficients.get(i).copied().unwrap_or(0.0)),
        rate_hz,
        format,
        tone_curve,
        line_delay_s,
    })
}

/// The optional `line_delay_s` key: 0 to 100 us per row.
fn line_delay(y: &Yaml, field: &str) -> Result<f64, String> {
    match y {
        Yaml::BadValue => Ok(0.0),
        y => {
            let v = number(y, field)?;
            if (0.0..=1e-4).contains(&v) {
                Ok(v)
            } else {
                Err(format!("`{field}`: {v} s per row is not a rolling shutter's line delay (0 to 0.0001)"))
            }
        }
    }
}

/// The optional `tone_curve` key.
fn tone_curve(y: &Yaml, field: &str) -> Result<ToneCurve, String> {
    match y {
        Yaml::BadValue => Ok(ToneCurve::Srgb),
        Yaml::String(s) if s == "srgb" => Ok(ToneCurve::Srgb),
        Yaml::String(s) if s == "linear" => Ok(ToneCurve::Linear),
        other => Err(format!("`{field}`: {other:?} is not a tone curve (srgb or linear)")),
    }
}

fn checked(camera: CameraModel) -> Result<CameraModel, String> {
    let (w, h) = (camera.width as f32, camera.height as f32);
    if !(camera.fx > 0.0 && camera.fy > 0.0 && camera.fx.is_finite() && camera.fy.is_finite()) {
        return Err(format!("the focal lengths {} and {} px must be positive", camera.fx, camera.fy));
    }
    if !(camera.cx > -0.5 && camera.cx < w - 0.5 && camera.cy > -0.5 && camera.cy < h - 0.5) {
        return Err(format!(
            "the principal point ({}, {}) px lies outside the {}x{} image",
            camera.cx, camera.cy, camera.width, camera.height
        ));
    }
    Ok(camera)
}

fn camera_info(doc: &Yaml) -> Result<Calibration, String> {
    let (width, height) = size(
        number(&doc["image_width"], "image_width")?,
        number(&doc["image_height"], "image_height")?,
        "image_width",
    )?;
    let k = list(&doc["camera_matrix"]["data"], "camera_matrix.data")?;
    if k.len() != 9 {
        return Err(format!(
            "`camera_matrix.data`: {} values; a 3x3 matrix (9, row-major) expected",
            k.len()
        ));
    }
    if k[1] != 0.0 || k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
        return Err(
            "`camera_matrix.data`: [fx, 0, cx, 0, fy, cy, 0, 0, 1] expected (a skew is not supported)".into(),
        );
    }
    let model = match &doc["distortion_model"] {
        Yaml::String(s) => s.clone(),
        Yaml::BadValue => "plumb_bob".into(),
        _ => return Err("`distortion_model` is not a name".into()),
    };
    let d = match &doc["distortion_coefficients"] {
        Yaml::BadValue => Vec::new(),
        y => list(&y["data"], "distortion_coefficients.data")?,
    };
    let distortion = if d.is_empty() {
        Distortion::default()
    } else {
        distortion(&model, &d, "distortion_coefficients.data")?
    };
    let tone =
        (tone_curve(&doc["tone_curve"], "tone_curve")?, line_delay(&doc["line_delay_s"], "line_delay_s")?);
    calibration(
        (width, height),
        [k[0], k[4], k[2], k[5]],
        distortion,
        &d,
        None,
        CalibFormat::CameraInfo,
        tone,
    )
}

fn kalibr(cam: &Yaml, prefix: &str) -> Result<Calibration, String> {
    let f = |name: &str| format!("{prefix}{name}");
    if let Yaml::String(m) = &cam["camera_model"]
        && m != "pinhole"
    {
        return Err(format!("`{}`: `{m}` is not supported (pinhole only)", f("camera_model")));
    }
    let r = list(&cam["resolution"], &f("resolution"))?;
    if r.len() != 2 {
        return Err(format!("`{}`: [width, height] expected", f("resolution")));
    }
    let (width, height) = size(r[0], r[1], &f("resolution"))?;
    let k = list(&cam["intrinsics"], &f("intrinsics"))?;
    if k.len() != 4 {
        return Err(format!("`{}`: [fu, fv, cu, cv] expected, {} values", f("intrinsics"), k.len()));
    }
    let model = match &cam["distortion_model"] {
        Yaml::String(s) => s.clone(),
        Yaml::BadValue => "radtan".into(),
        _ => return Err(format!("`{}` is not a name", f("distortion_model"))),
    };
    let (coeffs, field) = if cam["distortion_coeffs"].is_badvalue() {
        (&cam["distortion_coefficients"], f("distortion_coefficients"))
    } else {
        (&cam["distortion_coeffs"], f("distortion_coeffs"))
    };
    let d = if coeffs.is_badvalue() { Vec::new() } else { list(coeffs, &field)? };
    let distortion = if d.is_empty() { Distortion::default() } else { distortion(&model, &d, &field)? };
    let rate_hz = match &cam["rate_hz"] {
        Yaml::BadValue => None,
        y => Some(number(y, &f("rate_hz"))?),
    };
    let tone = (
        tone_curve(&cam["tone_curve"], &f("tone_curve"))?,
        line_delay(&cam["line_delay_s"], &f("line_delay_s"))?,
    );
    calibration((width, height), [k[0], k[1], k[2], k[3]], distortion, &d, rate_hz, CalibFormat::Kalibr, tone)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What ROS's camera_calibration writes for a wide-angle webcam.
    const CAMERA_INFO: &str = "\
image_width: 640
image_height: 480
camera_name: forward
camera_matrix:
  rows: 3
  cols: 3
  data: [322.5, 0, 318.25, 0, 321.75, 241.5, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.3, 0.09, 0.001, -0.0005, 0.002]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [322.5, 0, 318.25, 0, 0, 321.75, 241.5, 0, 0, 0, 1, 0]
";

    /// EuRoC MH_01's cam0/sensor.yaml (the dataset's published calibration).
    const EUROC: &str = "\
# General sensor definitions.
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
";

    #[test]
    fn a_camera_info_file_gives_its_intrinsics_and_distortion() {
        let c = parse(CAMERA_INFO).unwrap();
        assert_eq!(c.format, CalibFormat::CameraInfo);
        let m = c.camera;
        assert_eq!((m.width, m.height), (640, 480));
        assert_eq!((m.fx, m.fy, m.cx, m.cy), (322.5, 321.75, 318.25, 241.5));
        assert_eq!(m.distortion, Distortion { k1: -0.3, k2: 0.09, p1: 0.001, p2: -0.0005, k3: 0.002 });
        // The distortion is the one the detector undistorts with: barrel distortion (k1 < 0) pulled a point
        // near the corner inward, undistorting moves it back out, and the round trip returns the pixel.
        let px = geometry::Vec2::new(620.0, 460.0);
        let n = m.pixel_to_normalized(px);
        let naive = geometry::Vec2::new((px.x - m.cx) / m.fx, (px.y - m.cy) / m.fy);
        assert!(n.norm() > 1.05 * naive.norm(), "{n:?} {naive:?}");
        assert!((m.normalized_to_pixel(n) - px).norm() < 1e-2);
        // No tone curve in the file: sRGB, as webcams deliver; a file may say `linear`.
        assert_eq!(c.tone_curve, ToneCurve::Srgb);
        let linear = parse(&format!("{CAMERA_INFO}tone_curve: linear\n")).unwrap();
        assert_eq!(linear.tone_curve, ToneCurve::Linear);
        assert_eq!(parse(&format!("{CAMERA_INFO}tone_curve: srgb\n")).unwrap().tone_curve, ToneCurve::Srgb);
        // A global shutter unless the file gives the rolling shutter's line delay.
        assert_eq!(c.line_delay_s, 0.0);
        assert_eq!(parse(&format!("{CAMERA_INFO}line_delay_s: 3.0e-5\n")).unwrap().line_delay_s, 3.0e-5);
    }

    #[test]
    fn euroc_and_kalibr_camchain_files_give_theirs() {
        let c = parse(EUROC).unwrap();
        assert_eq!(c.format, CalibFormat::Kalibr);
        assert_eq!((c.camera.width, c.camera.height), (752, 480));
        assert_eq!(
            (c.camera.fx, c.camera.fy, c.camera.cx, c.camera.cy),
            (458.654, 457.296, 367.215, 248.375)
        );
        assert_eq!(c.camera.distortion.k1, -0.28340811f64 as f32);
        assert_eq!(c.camera.distortion.p2, 1.76187114e-05f64 as f32);
        assert_eq!(c.camera.distortion.k3, 0.0);
        assert_eq!(c.rate_hz, Some(20.0));
        assert_eq!(c.intrinsics_px, [458.654, 457.296, 367.215, 248.375]);
        assert_eq!(c.distortion, [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]);
        let chain = "cam1:\n  camera_model: pinhole\n  intrinsics: [400, 401, 300, 200]\n  resolution: [640, 400]\n\
                     cam0:\n  camera_model: pinhole\n  intrinsics: [458.6, 457.3, 367.2, 248.4]\n  \
                     distortion_model: radtan\n  distortion_coeffs: [-0.28, 0.07, 0.0002, 0.00002]\n  \
                     resolution: [752, 480]\n";
        let c = parse(chain).unwrap();
        assert_eq!((c.camera.width, c.camera.fx, c.camera.distortion.k1), (752, 458.6, -0.28));
        assert_eq!(c.tone_curve, ToneCurve::Srgb);
        let c = parse(&format!("{chain}  tone_curve: linear\n")).unwrap();
        assert_eq!(c.tone_curve, ToneCurve::Linear);
    }

    #[test]
    fn malformed_calibrations_are_refused_naming_the_field() {
        let cases: &[(&str, &str)] = &[
            ("", "empty"),
            ("[1, 2]", "mapping"),
            ("a: [1\n", "not YAML"),
            ("foo: 1\n", "neither a camera_info"),
            ("image_width: 640\nimage_height: 480\n", "`camera_matrix.data` is missing"),
            ("image_width: 640\nimage_height: 480\ncamera_matrix: {data: [1, 0, 2]}\n", "9, row-major"),
            ("image_width: 640\ncamera_matrix: {data: [1,0,2,0,1,2,0,0,1]}\n", "`image_height` is missing"),
            (
                "image_width: 64.5\nimage_height: 480\ncamera_matrix: {data: [1,0,2,0,1,2,0,0,1]}\n",
                "image size",
            ),
            (
                "image_width: 640\nimage_height: 480\ncamera_matrix: {data: [300,0,320,0,300,240,0,0,1]}\n\
                 distortion_model: equidistant\ndistortion_coefficients: {data: [0.1, 0, 0, 0]}\n",
                "equidistant",
            ),
            (
                "image_width: 640\nimage_height: 480\ncamera_matrix: {data: [300,0,320,0,300,240,0,0,1]}\n\
                 distortion_coefficients: {data: [0.1, x, 0, 0, 0]}\n",
                "`distortion_coefficients.data[1]` is not a number",
            ),
            (
                "image_width: 640\nimage_height: 480\ncamera_matrix: {data: [-3,0,320,0,300,240,0,0,1]}\n",
                "positive",
            ),
            (
                "image_width: 640\nimage_height: 480\ncamera_matrix: {data: [300,0,900,0,300,240,0,0,1]}\n",
                "outside",
            ),
            ("resolution: [752, 480]\nintrinsics: [458, 457, 367]\n", "[fu, fv, cu, cv]"),
            ("resolution: [752]\nintrinsics: [458, 457, 367, 248]\n", "[width, height]"),
            (
                "camera_model: omni\nresolution: [752, 480]\nintrinsics: [458, 457, 367, 248]\n",
                "pinhole only",
            ),
            ("cam0:\n  intrinsics: [458, 457, 367, 248]\n", "`cam0.resolution` is missing"),
            (
                "cam0:\n  intrinsics: [458, 457, 367, 248]\n  resolution: [752, 480]\n  tone_curve: gamma22\n",
                "`cam0.tone_curve`: String(\"gamma22\") is not a tone curve (srgb or linear)",
            ),
            (
                "image_width: 640\nimage_height: 480\ncamera_matrix: {data: [300,0,320,0,300,240,0,0,1]}\n\
                 tone_curve: 2.2\n",
                "`tone_curve`",
            ),
            (
                "image_width: 640\nimage_height: 480\ncamera_matrix: {data: [300,0,320,0,300,240,0,0,1]}\n\
                 line_delay_s: 0.03\n",
                "`line_delay_s`: 0.03 s per row is not a rolling shutter's line delay",
            ),
        ];
        for (text, want) in cases {
            let e = parse(text).expect_err(text);
            assert!(e.contains(want), "{text:?}: `{e}` does not say `{want}`");
        }
    }

    #[test]
    fn a_calibration_of_another_size_is_refused_with_both_sizes() {
        let c = parse(CAMERA_INFO).unwrap().camera;
        assert!(check_size(&c, 640, 480).is_ok());
        let e = check_size(&c, 1280, 720).unwrap_err();
        assert!(e.contains("640x480") && e.contains("1280x720"), "{e}");
        let e = load(Path::new("/nonexistent/forward.yaml")).unwrap_err();
        assert!(e.contains("/nonexistent/forward.yaml"), "{e}");
    }
}
