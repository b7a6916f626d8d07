use super::*;

/// BT.601 studio-range YUV of an RGB pixel (the camera's side, written independently of the decoder).
fn yuv(r: f32, g: f32, b: f32) -> (f32, f32, f32) {
    let y = 16.0 + (65.481 * r + 128.553 * g + 24.966 * b) / 255.0;
    let u = 128.0 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255.0;
    let v = 128.0 + (112.0 * r - 93.786 * g - 18.214 * b) / 255.0;
    (y, u, v)
}

/// An RGB image as a camera's YUYV buffer (chroma averaged over each pair of pixels).
pub(crate) fn rgb_to_yuyv(rgb: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(rgb.len() / 3 * 2);
    for pair in rgb.chunks_exact(6) {
        let a = yuv(pair[0] as f32, pair[1] as f32, pair[2] as f32);
        let b = yuv(pair[3] as f32, pair[4] as f32, pair[5] as f32);
        let q = |v: f32| v.round().clamp(0.0, 255.0) as u8;
        out.extend_from_slice(&[q(a.0), q((a.1 + b.1) / 2.0), q(b.0), q((a.2 + b.2) / 2.0)]);
    }
    out
}

#[test]
fn yuyv_reference_colours_decode_to_their_rgb() {
    // BT.601 studio range: black Y16, white Y235, 75 % red (Y 65, U 100, V 212 in the colour-bar tables) and
    // pure red (Y 81, U 90, V 240).
    let px = |y: u8, u: u8, v: u8| yuyv_to_image(&[y, u, y, v], 2, 1, 3).unwrap()[..3].to_vec();
    assert_eq!(px(16, 128, 128), [0, 0, 0]);
    assert_eq!(px(235, 128, 128), [255, 255, 255]);
    let red = px(81, 90, 240);
    assert!(red[0] >= 253 && red[1] <= 1 && red[2] <= 1, "{red:?}");
    let red75 = px(65, 100, 212);
    assert!((red75[0] as i32 - 191).abs() <= 2 && red75[1] <= 2 && red75[2] <= 2, "{red75:?}");
    // Grey is the luma, rescaled to full range (16 -> 0, 126 -> 128, 235 -> 255).
    assert_eq!(yuyv_to_image(&[16, 0, 126, 255, 235, 7, 235, 9], 4, 1, 1).unwrap(), [0, 128, 255, 255]);
}

#[test]
fn colours_survive_yuyv_within_the_rounding_and_grey_keeps_every_column() {
    // Colours constant over each pair of pixels (what 4:2:2 keeps whole): the only loss is the rounding of Y,
    // U and V to 8 bits, at most 1.164 / 2 + 2.017 / 2 = 1.6 levels (blue), so 2 after rounding.
    let (w, h) = (64, 8);
    let rgb: Vec<u8> = (0..w * h)
        .flat_map(|i| {
            let x = ((i % w) / 2) as u8;
            [x * 7 + 10, 230 - x * 6, 40 + x * 5 + (i / w) as u8 * 3]
        })
        .collect();
    let back = yuyv_to_image(&rgb_to_yuyv(&rgb), w, h, 3).unwrap();
    let worst = rgb.iter().zip(&back).map(|(a, b)| (*a as i32 - *b as i32).abs()).max().unwrap();
    assert!(worst <= 2, "worst channel error {worst}");
    // Grey has the full horizontal resolution: a one-pixel checkerboard of luma survives.
    let yuyv: Vec<u8> = (0..w * h / 2).flat_map(|_| [40u8, 128, 200, 128]).collect();
    let grey = yuyv_to_image(&yuyv, w, h, 1).unwrap();
    assert!(grey.chunks_exact(2).all(|p| p == [28, 214]), "{:?}", &grey[..4]);
    // A buffer shorter than its image is refused with both lengths.
    let e = yuyv_to_image(&rgb_to_yuyv(&rgb)[..100], w, h, 3).unwrap_err();
    assert_eq!(e, BufferError::Short(100, w * h * 2));
    assert!(e.to_string().contains("100 bytes, 1024 needed"), "{e}");
}

#[test]
fn kernel_timestamps_move_to_the_station_clock() {
    // A buffer stamped 30 ms before the clocks were read together: 30 ms before the Unix time read.
    let unix = 1_764_000_000_000_000;
    assert_eq!(monotonic_to_unix_us(5_000_000 - 30_000, 5_000_000, unix), unix - 30_000);
    // A monotonic clock far ahead of the Unix one (never in practice) does not wrap.
    assert_eq!(monotonic_to_unix_us(0, u64::MAX / 2, 10), 0);
}

#[test]
fn gaps_in_the_kernels_frame_numbers_are_counted_as_drops() {
    let mut c = CaptureCounters::default();
    c.sequence(None, 7);
    c.sequence(Some(7), 8);
    c.sequence(Some(8), 11);
    assert_eq!((c.buffers, c.dropped), (3, 2));
    // Across the counter's wrap.
    c.sequence(Some(u32::MAX), 1);
    assert_eq!((c.buffers, c.dropped), (4, 3));
    // A repeated number (a driver restarting its count) is no drop.
    c.sequence(Some(1), 1);
    assert_eq!(c.dropped, 3);
}

#[test]
fn formats_by_fourcc() {
    for f in [PixelFormat::Mjpeg, PixelFormat::Yuyv] {
        assert_eq!(PixelFormat::from_fourcc(f.fourcc()), Some(f));
    }
    assert_eq!(PixelFormat::from_fourcc(*b"YUY2"), Some(PixelFormat::Yuyv));
    assert_eq!(PixelFormat::from_fourcc(*b"H264"), None);
}

#[test]
fn what_is_not_a_jpeg_is_an_error_not_a_panic() {
    for bytes in [&b""[..], b"\xFF\xD8\xFF", b"not a jpeg at all", &[0xFF; 64]] {
        assert!(matches!(mjpeg_to_image(bytes, 2, 2, 3), Err(BufferError::Jpeg(_))));
    }
}
