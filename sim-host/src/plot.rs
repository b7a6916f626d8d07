//! Time-series plots as PNG images, drawn without any system font or plotting library: axes with 1-2-5
//! ticks, labelled with a built-in 5x7 bitmap font, a legend, shaded time spans, solid and dashed lines.
use crate::imageio::RgbImage;

/// One curve.
#[derive(Clone, Debug)]
pub struct Series<'a> {
    /// Legend entry.
    pub name: &'a str,
    /// Colour.
    pub color: [u8; 3],
    /// Abscissae.
    pub xs: &'a [f64],
    /// Ordinates (NaN breaks the line).
    pub ys: &'a [f64],
    /// Dashed instead of solid.
    pub dashed: bool,
}

/// A plot.
#[derive(Clone, Debug)]
pub struct Plot<'a> {
    /// Title (top).
    pub title: &'a str,
    /// Label of the x axis.
    pub x_label: &'a str,
    /// Label of the y axis.
    pub y_label: &'a str,
    /// The curves.
    pub series: Vec<Series<'a>>,
    /// Shaded x intervals with a caption (e.g. the tracking phase).
    pub spans: Vec<(f64, f64, &'a str)>,
    /// Image size (px).
    pub size: (usize, usize),
}

const GLYPHS: &[(char, &str)] = &[
    ('0', "01110,10001,10011,10101,11001,10001,01110"),
    ('1', "00100,01100,00100,00100,00100,00100,01110"),
    ('2', "01110,10001,00001,00010,00100,01000,11111"),
    ('3', "11111,00010,00100,00010,00001,10001,01110"),
    ('4', "00010,00110,01010,10010,11111,00010,00010"),
    ('5', "11111,10000,11110,00001,00001,10001,01110"),
    ('6', "00110,01000,10000,11110,10001,10001,01110"),
    ('7', "11111,00001,00010,00100,01000,01000,01000"),
    ('8', "01110,10001,10001,01110,10001,10001,01110"),
    ('9', "01110,10001,10001,01111,00001,00010,01100"),
    ('A', "01110,10001,10001,10001,11111,10001,10001"),
    ('B', "11110,10001,10001,11110,10001,10001,11110"),
    ('C', "01110,10001,10000,10000,10000,10001,01110"),
    ('D', "11100,10010,10001,10001,10001,10010,11100"),
    ('E', "11111,10000,10000,11110,10000,10000,11111"),
    ('F', "11111,10000,10000,11110,10000,10000,10000"),
    ('G', "01110,10001,10000,10111,10001,10001,01111"),
    ('H', "10001,10001,10001,11111,10001,10001,10001"),
    ('I', "01110,00100,00100,00100,00100,00100,01110"),
    ('J', "00111,00010,00010,00010,00010,10010,01100"),
    ('K', "10001,10010,10100,11000,10100,10010,10001"),
    ('L', "10000,10000,10000,10000,10000,10000,11111"),
    ('M', "10001,11011,10101,10101,10001,10001,10001"),
    ('N', "10001,10001,11001,10101,10011,10001,10001"),
    ('O', "01110,10001,10001,10001,10001,10001,01110"),
    ('P', "11110,10001,10001,11110,10000,10000,10000"),
    ('Q', "01110,10001,10001,10001,10101,10010,01101"),
    ('R', "11110,10001,10001,11110,10100,10010,10001"),
    ('S', "01111,10000,10000,01110,00001,00001,11110"),
    ('T', "11111,00100,00100,00100,00100,00100,00100"),
    ('U', "10001,10001,10001,10001,10001,10001,01110"),
    ('V', "10001,10001,10001,10001,10001,01010,00100"),
    ('W', "10001,10001,10001,10101,10101,10101,01010"),
    ('X', "10001,10001,01010,00100,01010,10001,10001"),
    ('Y', "10001,10001,10001,01010,00100,00100,00100"),
    ('Z', "11111,00001,00010,00100,01000,10000,11111"),
    ('a', "00000,00000,01110,00001,01111,10001,01111"),
    ('b', "10000,10000,10110,11001,10001,10001,11110"),
    ('c', "00000,00000,01110,10000,10000,10001,01110"),
    ('d', "00001,00001,01101,10011,10001,10001,01111"),
    ('e', "00000,00000,01110,10001,11111,10000,01110"),
    ('f', "00110,01001,01000,11100,01000,01000,01000"),
    ('g', "00000,01111,10001,10001,01111,00001,01110"),
    ('h', "10000,10000,10110,11001,10001,10001,10001"),
    ('i', "00100,00000,01100,00100,00100,00100,01110"),
    ('j', "00010,00000,00110,00010,00010,10010,01100"),
    ('k', "10000,10000,10010,10100,11000,10100,10010"),
    ('l', "01100,00100,00100,00100,00100,00100,01110"),
    ('m', "00000,00000,11010,10101,10101,10001,10001"),
    ('n', "00000,00000,10110,11001,10001,10001,10001"),
    ('o', "00000,00000,01110,10001,10001,10001,01110"),
    ('p', "00000,00000,11110,10001,11110,10000,10000"),
    ('q', "00000,00000,01101,10011,01111,00001,00001"),
    ('r', "00000,00000,10110,11001,10000,10000,10000"),
    ('s', "00000,00000,01110,10000,01110,00001,11110"),
    ('t', "01000,01000,11100,01000,01000,01001,00110"),
    ('u', "00000,00000,10001,10001,10001,10011,01101"),
    ('v', "00000,00000,10001,10001,10001,01010,00100"),
    ('w', "00000,00000,10001,10001,10101,10101,01010"),
    ('x', "00000,00000,10001,01010,00100,01010,10001"),
    ('y', "00000,00000,10001,10001,01111,00001,01110"),
    ('z', "00000,00000,11111,00010,00100,01000,11111"),
    (' ', "00000,00000,00000,00000,00000,00000,00000"),
    ('.', "00000,00000,00000,00000,00000,01100,01100"),
    (',', "00000,00000,00000,00000,01100,00100,01000"),
    ('-', "00000,00000,00000,11111,00000,00000,00000"),
    (':', "00000,01100,01100,00000,01100,01100,00000"),
    ('(', "00010,00100,01000,01000,01000,00100,00010"),
    (')', "01000,00100,00010,00010,00010,00100,01000"),
    ('/', "00000,00001,00010,00100,01000,10000,00000"),
    ('=', "00000,00000,11111,00000,11111,00000,00000"),
    ('+', "00000,00100,00100,11111,00100,00100,00000"),
    ('_', "00000,00000,00000,00000,00000,00000,11111"),
    ('%', "11000,11001,00010,00100,01000,10011,00011"),
    ('[', "01110,01000,01000,01000,01000,01000,01110"),
    (']', "01110,00010,00010,00010,00010,00010,01110"),
    ('\'', "01100,00100,01000,00000,00000,00000,00000"),
    ('^', "00100,01010,10001,00000,00000,00000,00000"),
    ('*', "00000,00100,10101,01110,10101,00100,00000"),
    ('<', "00010,00100,01000,10000,01000,00100,00010"),
    ('>', "01000,00100,00010,00001,00010,00100,01000"),
];

fn glyph(c: char) -> [u8; 7] {
    let rows =
        GLYPHS.iter().find(|(g, _)| *g == c).map_or("11111,10001,10001,10001,10001,10001,11111", |(_, r)| r);
    let mut out = [0u8; 7];
    for (i, r) in rows.split(',').enumerate().take(7) {
        out[i] = u8::from_str_radix(r, 2).unwrap_or(0);
    }
    out
}

/// Text width in pixels at a scale.
pub fn text_width(s: &str, scale: usize) -> usize {
    s.chars().count() * 6 * scale
}

/// Draws text with its top-left corner at `(x, y)`.
pub fn draw_text(img: &mut RgbImage, x: i64, y: i64, s: &str, scale: usize, color: [u8; 3]) {
    for (k, c) in s.chars().enumerate() {
        let g = glyph(c);
        let x0 = x + (k * 6 * scale) as i64;
        for (row, bits) in g.iter().enumerate() {
            for col in 0..5 {
                if bits & (1 << (4 - col)) != 0 {
                    for dy in 0..scale {
                        for dx in 0..scale {
                            img.put(x0 + (col * scale + dx) as i64, y + (row * scale + dy) as i64, color);
                        }
                    }
                }
            }
        }
    }
}

fn fill(img: &mut RgbImage, x0: i64, y0: i64, x1: i64, y1: i64, c: [u8; 3]) {
    for y in y0.min(y1)..=y0.max(y1) {
        for x in x0.min(x1)..=x0.max(x1) {
            img.put(x, y, c);
        }
    }
}

/// A thick line from `(x0, y0)` to `(x1, y1)`; `dash` is the phase for dashed lines (`None`: solid).
fn line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), c: [u8; 3], width: i64, dash: Option<&mut f64>) {
    let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt();
    let n = len.ceil().max(1.0) as usize;
    let mut dash = dash;
    for i in 0..=n {
        let t = i as f64 / n as f64;
        if let Some(d) = dash.as_deref_mut() {
            let on = (*d % 14.0) < 8.0;
            *d += if i == 0 { 0.0 } else { len / n as f64 };
            if !on {
                continue;
            }
        }
        let (x, y) = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
        let h = width / 2;
        fill(
            img,
            x.round() as i64 - h,
            y.round() as i64 - h,
            x.round() as i64 - h + width - 1,
            y.round() as i64 - h + width - 1,
            c,
        );
    }
}

/// "Nice" tick step (1, 2 or 5 times a power of ten) for about `n` ticks over `span`.
pub fn nice_step(span: f64, n: f64) -> f64 {
    if !(span > 0.0) || !span.is_finite() {
        return 1.0;
    }
    let raw = span / n;
    let p = 10f64.powf(raw.log10().floor());
    let m = raw / p;
    let f = if m < 1.5 {
        1.0
    } else if m < 3.5 {
        2.0
    } else if m < 7.5 {
        5.0
    } else {
        10.0
    };
    f * p
}

fn fmt_tick(v: f64, step: f64) -> String {
    let decimals = if step >= 1.0 { 0 } else { (-step.log10()).ceil().clamp(0.0, 6.0) as usize };
    let s = format!("{v:.decimals$}");
    if s == "-0" || s.chars().all(|c| c == '-' || c == '0' || c == '.') && s.starts_with('-') {
        s[1..].to_string()
    } else {
        s
    }
}

/// Renders a plot.
pub fn render(p: &Plot<'_>) -> RgbImage {
    let (w, h) = p.size;
    let mut img = RgbImage { width: w, height: h, data: vec![255; 3 * w * h] };
    let (left, right, top, bottom) = (110i64, 30i64, 56i64, 64i64);
    let (pw, ph) = (w as i64 - left - right, h as i64 - top - bottom);
    // Data ranges.
    let (mut x0, mut x1, mut y0, mut y1) =
        (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for s in &p.series {
        for (&x, &y) in s.xs.iter().zip(s.ys) {
            if x.is_finite() && y.is_finite() {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
        }
    }
    if !x0.is_finite() {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    if x1 - x0 < 1e-9 {
        x1 = x0 + 1.0;
    }
    let pad = ((y1 - y0) * 0.08).max(1e-3);
    (y0, y1) = (y0 - pad, y1 + pad);
    let ystep = nice_step(y1 - y0, 6.0);
    let xstep = nice_step(x1 - x0, 10.0);
    let sx = |x: f64| left as f64 + (x - x0) / (x1 - x0) * pw as f64;
    let sy = |y: f64| top as f64 + (y1 - y) / (y1 - y0) * ph as f64;
    let grey = [225, 225, 225];
    let dark = [40, 40, 40];
    // Shaded spans.
    for &(a, b, label) in &p.spans {
        let (xa, xb) = (sx(a.max(x0)), sx(b.min(x1)));
        if xb > xa {
            fill(&mut img, xa as i64, top, xb as i64, top + ph, [238, 244, 252]);
            draw_text(&mut img, xa as i64 + 6, top + 6, label, 2, [120, 140, 170]);
        }
    }
    // Grid and ticks.
    let mut v = (y0 / ystep).ceil() * ystep;
    while v <= y1 + 1e-12 {
        let y = sy(v) as i64;
        fill(&mut img, left, y, left + pw, y, grey);
        let s = fmt_tick(v, ystep);
        draw_text(&mut img, left - 10 - text_width(&s, 2) as i64, y - 7, &s, 2, dark);
        v += ystep;
    }
    let mut v = (x0 / xstep).ceil() * xstep;
    while v <= x1 + 1e-12 {
        let x = sx(v) as i64;
        fill(&mut img, x, top, x, top + ph, grey);
        let s = fmt_tick(v, xstep);
        draw_text(&mut img, x - text_width(&s, 2) as i64 / 2, top + ph + 10, &s, 2, dark);
        v += xstep;
    }
    // Frame.
    for (a, b) in [
        ((left, top), (left + pw, top)),
        ((left, top + ph), (left + pw, top + ph)),
        ((left, top), (left, top + ph)),
        ((left + pw, top), (left + pw, top + ph)),
    ] {
        fill(&mut img, a.0, a.1, b.0, b.1, dark);
    }
    // Curves, clipped to the plot area.
    for s in &p.series {
        let mut dash = if s.dashed { Some(0.0f64) } else { None };
        let mut prev: Option<(f64, f64)> = None;
        for (&x, &y) in s.xs.iter().zip(s.ys) {
            if !(x.is_finite() && y.is_finite()) {
                prev = None;
                continue;
            }
            let pt = (sx(x), sy(y).clamp(top as f64, (top + ph) as f64));
            if let Some(a) = prev {
                line(&mut img, a, pt, s.color, 2, dash.as_mut());
            }
            prev = Some(pt);
        }
    }
    // Title, labels, legend.
    draw_text(&mut img, left, 14, p.title, 3, dark);
    draw_text(
        &mut img,
        left + pw / 2 - text_width(p.x_label, 2) as i64 / 2,
        h as i64 - 26,
        p.x_label,
        2,
        dark,
    );
    draw_text(&mut img, 8, top - 22, p.y_label, 2, dark);
    let mut lx = left + pw;
    for s in p.series.iter().rev() {
        lx -= text_width(s.name, 2) as i64 + 44;
        let ly = top - 20;
        if s.dashed {
            let mut d = 0.0;
            line(
                &mut img,
                (lx as f64, ly as f64 + 7.0),
                (lx as f64 + 30.0, ly as f64 + 7.0),
                s.color,
                3,
                Some(&mut d),
            );
        } else {
            fill(&mut img, lx, ly + 6, lx + 30, ly + 8, s.color);
        }
        draw_text(&mut img, lx + 36, ly, s.name, 2, dark);
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_numbers() {
        assert_eq!(nice_step(10.0, 10.0), 1.0);
        assert_eq!(nice_step(2.3, 6.0), 0.5);
        assert!((nice_step(0.07, 6.0) - 0.01).abs() < 1e-12);
        assert_eq!(fmt_tick(0.5, 0.5), "0.5");
        assert_eq!(fmt_tick(-0.0, 0.5), "0.0");
    }

    #[test]
    fn plot_draws_its_curves() {
        let xs: Vec<f64> = (0..100).map(|i| i as f64 * 0.1).collect();
        let ys: Vec<f64> = xs.iter().map(|x| x.sin()).collect();
        let img = render(&Plot {
            title: "test",
            x_label: "time (s)",
            y_label: "y (m)",
            series: vec![Series { name: "truth", color: [200, 30, 30], xs: &xs, ys: &ys, dashed: false }],
            spans: vec![(2.0, 5.0, "tracking")],
            size: (800, 400),
        });
        let red = img.data.chunks_exact(3).filter(|p| p == &[200, 30, 30]).count();
        assert!(red > 500, "{red}");
        assert!(img.data.chunks_exact(3).any(|p| p == [40, 40, 40]), "text and frame");
    }
}
