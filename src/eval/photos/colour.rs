//! Colours of image regions and their differences: the per-channel median of 8-bit sRGB
//! pixels, sRGB → CIELAB (D65 white, IEC 61966-2-1 transfer curve), and CIEDE2000 (CIE
//! 142-2001; `palette`'s implementation, checked against Sharma, Wu & Dalal 2005, Table 1).

use palette::color_difference::Ciede2000;
use palette::white_point::D65;
use palette::{IntoColor, Lab, Srgb};

/// An 8-bit sRGB colour.
pub type Srgb8 = [u8; 3];

/// CIELAB `[L*, a*, b*]` of an 8-bit sRGB colour, D65 white.
pub fn srgb_to_lab(rgb: Srgb8) -> [f64; 3] {
    let lab: Lab<D65, f64> = Srgb::new(rgb[0], rgb[1], rgb[2])
        .into_format::<f64>()
        .into_color();
    [lab.l, lab.a, lab.b]
}

/// CIEDE2000 colour difference ΔE00 of two CIELAB colours (kL = kC = kH = 1).
pub fn ciede2000_lab(a: [f64; 3], b: [f64; 3]) -> f64 {
    let lab = |c: [f64; 3]| Lab::<D65, f64>::new(c[0], c[1], c[2]);
    lab(a).difference(lab(b))
}

/// CIEDE2000 difference of two 8-bit sRGB colours (through CIELAB, D65).
pub fn ciede2000(a: Srgb8, b: Srgb8) -> f64 {
    ciede2000_lab(srgb_to_lab(a), srgb_to_lab(b))
}

/// `#rrggbb`.
pub fn hex(rgb: Srgb8) -> String {
    format!("#{:02x}{:02x}{:02x}", rgb[0], rgb[1], rgb[2])
}

/// Per-channel 8-bit histograms of a set of pixels, for exact medians.
#[derive(Debug, Clone)]
pub struct ChannelHistogram {
    counts: [[u32; 256]; 3],
    pixels: usize,
}

impl Default for ChannelHistogram {
    fn default() -> Self {
        Self {
            counts: [[0; 256]; 3],
            pixels: 0,
        }
    }
}

impl ChannelHistogram {
    /// Counts one pixel.
    pub fn add(&mut self, rgb: Srgb8) {
        for (counts, v) in self.counts.iter_mut().zip(rgb) {
            counts[usize::from(v)] += 1;
        }
        self.pixels += 1;
    }

    /// Pixels counted.
    pub fn pixels(&self) -> usize {
        self.pixels
    }

    /// The median of each channel (the lower median for an even count); `None` when empty.
    pub fn median(&self) -> Option<Srgb8> {
        if self.pixels == 0 {
            return None;
        }
        let rank = (self.pixels as u64 - 1) / 2;
        Some(self.counts.map(|counts| {
            let mut seen = 0u64;
            let mut value = 255u8;
            for (v, c) in counts.iter().enumerate() {
                seen += u64::from(*c);
                if seen > rank {
                    value = v as u8;
                    break;
                }
            }
            value
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sharma, Wu & Dalal (2005), Table 1: pairs 1-4, 7, 17-20 and 25.
    const SHARMA: [([f64; 3], [f64; 3], f64); 10] = [
        ([50.0, 2.6772, -79.7751], [50.0, 0.0, -82.7485], 2.0425),
        ([50.0, 3.1571, -77.2803], [50.0, 0.0, -82.7485], 2.8615),
        ([50.0, 2.8361, -74.0200], [50.0, 0.0, -82.7485], 3.4412),
        ([50.0, -1.3802, -84.2814], [50.0, 0.0, -82.7485], 1.0000),
        ([50.0, 0.0, 0.0], [50.0, -1.0, 2.0], 2.3669),
        ([50.0, 2.5, 0.0], [73.0, 25.0, -18.0], 27.1492),
        ([50.0, 2.5, 0.0], [61.0, -5.0, 29.0], 22.8977),
        ([50.0, 2.5, 0.0], [56.0, -27.0, -3.0], 31.9030),
        ([50.0, 2.5, 0.0], [58.0, 24.0, 15.0], 19.4535),
        (
            [60.2574, -34.0099, 36.2677],
            [60.4626, -34.1751, 39.4387],
            1.2644,
        ),
    ];

    #[test]
    fn ciede2000_matches_sharmas_test_pairs() {
        for (a, b, want) in SHARMA {
            let got = ciede2000_lab(a, b);
            assert!((got - want).abs() < 5e-5, "{a:?} {b:?}: {got} vs {want}");
            let back = ciede2000_lab(b, a);
            assert!((back - want).abs() < 5e-5, "symmetric: {back} vs {want}");
        }
        assert_eq!(ciede2000([12, 200, 99], [12, 200, 99]), 0.0);
    }

    #[test]
    fn srgb_goes_to_d65_lab() {
        let close =
            |got: [f64; 3], want: [f64; 3]| got.iter().zip(want).all(|(g, w)| (g - w).abs() < 0.02);
        let white = srgb_to_lab([255, 255, 255]);
        assert!(close(white, [100.0, 0.0, 0.0]), "{white:?}");
        assert!(close(srgb_to_lab([0, 0, 0]), [0.0, 0.0, 0.0]));
        // sRGB primaries under D65 (Lindbloom's calculator, sRGB, D65, no adaptation).
        let red = srgb_to_lab([255, 0, 0]);
        assert!(close(red, [53.2408, 80.0925, 67.2032]), "{red:?}");
        let blue = srgb_to_lab([0, 0, 255]);
        assert!(close(blue, [32.2970, 79.1875, -107.8602]), "{blue:?}");
        let grey = srgb_to_lab([119, 119, 119]);
        assert!(
            (grey[0] - 50.03).abs() < 0.05 && grey[1].abs() < 0.01,
            "{grey:?}"
        );
    }

    #[test]
    fn medians_are_per_channel() {
        let mut h = ChannelHistogram::default();
        assert_eq!(h.median(), None);
        for rgb in [[10, 200, 0], [20, 100, 255], [30, 0, 128], [250, 50, 7]] {
            h.add(rgb);
        }
        assert_eq!(h.pixels(), 4);
        assert_eq!(h.median(), Some([20, 50, 7]));
        h.add([255, 255, 255]);
        assert_eq!(h.median(), Some([30, 100, 128]));
        assert_eq!(hex([255, 8, 171]), "#ff08ab");
    }
}
