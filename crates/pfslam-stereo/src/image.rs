//! Minimal 8-bit images (grey and interleaved RGB), Bayer demosaicing and PNG loading.

use super::StereoError;
use rayon::prelude::*;

pub use pfslam::config::stereo::{BayerPattern, Demosaic};
use std::path::Path;

/// A single-channel 8-bit image, row-major.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct GrayImage {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// `width * height` samples, row after row.
    pub data: Vec<u8>,
}

/// An interleaved 8-bit RGB image, row-major (`data[3 * (y * width + x) + c]`).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct RgbImage {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// `3 * width * height` samples.
    pub data: Vec<u8>,
}

impl GrayImage {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        GrayImage {
            width,
            height,
            data: vec![0; width * height],
        }
    }

    /// Resizes (and zeroes when the size changes) so the buffer can be reused.
    pub fn reshape(&mut self, width: usize, height: usize) {
        if self.width != width || self.height != height || self.data.len() != width * height {
            self.width = width;
            self.height = height;
            self.data.clear();
            self.data.resize(width * height, 0);
        }
    }

    /// The sample at `(x, y)`.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.width + x]
    }
}

impl RgbImage {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        RgbImage {
            width,
            height,
            data: vec![0; 3 * width * height],
        }
    }

    /// Resizes (and zeroes when the size changes) so the buffer can be reused.
    pub fn reshape(&mut self, width: usize, height: usize) {
        if self.width != width || self.height != height || self.data.len() != 3 * width * height {
            self.width = width;
            self.height = height;
            self.data.clear();
            self.data.resize(3 * width * height, 0);
        }
    }

    /// The pixel at `(x, y)`.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (y * self.width + x);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Luma (ITU-R BT.601 weights, integer arithmetic) into `out`.
    pub fn to_gray_into(&self, out: &mut GrayImage) {
        out.reshape(self.width, self.height);
        out.data
            .par_chunks_mut(self.width.max(1))
            .zip(self.data.par_chunks(3 * self.width.max(1)))
            .for_each(|(g, rgb)| {
                for (o, p) in g.iter_mut().zip(rgb.chunks_exact(3)) {
                    let v = 299 * p[0] as u32 + 587 * p[1] as u32 + 114 * p[2] as u32;
                    *o = ((v + 500) / 1000) as u8;
                }
            });
    }
}

/// Loads an 8-bit single-channel PNG (a raw Bayer frame or a grey image).
pub fn load_gray_png(path: &Path) -> Result<GrayImage, StereoError> {
    let img = image::open(path).map_err(|e| StereoError::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    match img {
        image::DynamicImage::ImageLuma8(g) => {
            let (w, h) = g.dimensions();
            Ok(GrayImage {
                width: w as usize,
                height: h as usize,
                data: g.into_raw(),
            })
        }
        other => Err(StereoError::Image {
            path: path.to_path_buf(),
            message: format!(
                "expected an 8-bit single-channel PNG (raw Bayer), got {:?}",
                other.color()
            ),
        }),
    }
}

/// Loads any 8-bit PNG as RGB (grey is replicated into the three channels).
pub fn load_rgb_png(path: &Path) -> Result<RgbImage, StereoError> {
    let img = image::open(path).map_err(|e| StereoError::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    let rgb = img.to_rgb8();
    let (w, h) = rgb.dimensions();
    Ok(RgbImage {
        width: w as usize,
        height: h as usize,
        data: rgb.into_raw(),
    })
}

fn encode_png(
    data: &[u8],
    width: usize,
    height: usize,
    colour: image::ExtendedColorType,
) -> Result<Vec<u8>, StereoError> {
    let mut bytes = Vec::new();
    let enc = image::codecs::png::PngEncoder::new(&mut bytes);
    image::ImageEncoder::write_image(enc, data, width as u32, height as u32, colour).map_err(
        |e| StereoError::Image {
            path: "<png>".into(),
            message: e.to_string(),
        },
    )?;
    Ok(bytes)
}

/// Encodes an RGB image as PNG bytes.
pub fn encode_rgb_png(img: &RgbImage) -> Result<Vec<u8>, StereoError> {
    encode_png(
        &img.data,
        img.width,
        img.height,
        image::ExtendedColorType::Rgb8,
    )
}

/// Encodes a grey (or raw Bayer) image as an 8-bit single-channel PNG.
pub fn encode_gray_png(img: &GrayImage) -> Result<Vec<u8>, StereoError> {
    encode_png(
        &img.data,
        img.width,
        img.height,
        image::ExtendedColorType::L8,
    )
}

/// Mosaics an RGB image into a single-channel Bayer frame (keeps each pixel's own channel).
pub fn mosaic(rgb: &RgbImage, pattern: BayerPattern) -> GrayImage {
    let mut out = GrayImage::new(rgb.width, rgb.height);
    for y in 0..rgb.height {
        for x in 0..rgb.width {
            out.data[y * rgb.width + x] = rgb.data[3 * (y * rgb.width + x) + pattern.channel(x, y)];
        }
    }
    out
}

/// Reflect-101 index (`-1 -> 1`, `n -> n - 2`): keeps the Bayer phase at the borders.
#[inline]
fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let mut i = i;
    if i < 0 {
        i = -i;
    }
    if i >= n {
        i = 2 * (n - 1) - i;
    }
    i.clamp(0, n - 1) as usize
}

/// Demosaics a raw Bayer frame into `out` (reshaped as needed). Images smaller than 2x2 are
/// rejected.
pub fn demosaic_into(
    raw: &GrayImage,
    pattern: BayerPattern,
    method: Demosaic,
    out: &mut RgbImage,
) -> Result<(), StereoError> {
    let (w, h) = (raw.width, raw.height);
    if w < 2 || h < 2 || raw.data.len() != w * h {
        return Err(StereoError::Size(format!(
            "Bayer frame {w}x{h} with {} samples",
            raw.data.len()
        )));
    }
    out.reshape(w, h);
    out.data
        .par_chunks_mut(3 * w)
        .enumerate()
        .for_each(|(y, row)| {
            let interior_y = y >= 2 && y + 2 < h;
            for x in 0..w {
                let px = if interior_y && x >= 2 && x + 2 < w {
                    // Fast path: no reflection needed.
                    let at = |dx: isize, dy: isize| -> i32 {
                        raw.data[(y as isize + dy) as usize * w + (x as isize + dx) as usize] as i32
                    };
                    demosaic_pixel(&at, pattern, method, x, y)
                } else {
                    let at = |dx: isize, dy: isize| -> i32 {
                        let xx = reflect(x as isize + dx, w);
                        let yy = reflect(y as isize + dy, h);
                        raw.data[yy * w + xx] as i32
                    };
                    demosaic_pixel(&at, pattern, method, x, y)
                };
                row[3 * x..3 * x + 3].copy_from_slice(&px);
            }
        });
    Ok(())
}

#[inline]
fn clamp_u8(v_times_16: i32) -> u8 {
    // Values are kept multiplied by 16 so MHC's half weights stay exact: round and clamp.
    ((v_times_16 + 8).div_euclid(16)).clamp(0, 255) as u8
}

#[inline]
fn demosaic_pixel<F: Fn(isize, isize) -> i32>(
    at: &F,
    pattern: BayerPattern,
    method: Demosaic,
    x: usize,
    y: usize,
) -> [u8; 3] {
    let c = pattern.channel(x, y);
    let centre = at(0, 0);
    // The channel of the horizontal neighbour tells a green pixel's row type.
    let horiz = pattern.channel(x ^ 1, y);
    let lr = at(-1, 0) + at(1, 0);
    let ud = at(0, -1) + at(0, 1);
    let cross = lr + ud;
    let diag = at(-1, -1) + at(1, -1) + at(-1, 1) + at(1, 1);
    let mut v16 = [0i32; 3];
    v16[c] = 16 * centre;
    match method {
        Demosaic::Bilinear => {
            if c == 1 {
                // Green site: the horizontal neighbours carry `horiz`, the vertical the other.
                v16[horiz] = 8 * lr;
                v16[2 - horiz] = 8 * ud;
            } else {
                v16[1] = 4 * cross;
                v16[2 - c] = 4 * diag;
            }
        }
        Demosaic::MalvarHeCutler => {
            let far_lr = at(-2, 0) + at(2, 0);
            let far_ud = at(0, -2) + at(0, 2);
            if c == 1 {
                // (5 c + 4 lr - diag - far_lr + far_ud / 2) / 8, and its transpose.
                v16[horiz] = 10 * centre + 8 * lr - 2 * diag - 2 * far_lr + far_ud;
                v16[2 - horiz] = 10 * centre + 8 * ud - 2 * diag - 2 * far_ud + far_lr;
            } else {
                // Green: (4 c + 2 cross - far_cross) / 8.
                v16[1] = 8 * centre + 4 * cross - 2 * (far_lr + far_ud);
                // Opposite chroma: (6 c + 2 diag - 3/2 far_cross) / 8.
                v16[2 - c] = 12 * centre + 4 * diag - 3 * (far_lr + far_ud);
            }
        }
    }
    [clamp_u8(v16[0]), clamp_u8(v16[1]), clamp_u8(v16[2])]
}

/// Peak signal-to-noise ratio (dB) between two RGB images of the same size, over the pixels at
/// least `border` away from the edges. `f64::INFINITY` when identical.
pub fn psnr_db(a: &RgbImage, b: &RgbImage, border: usize) -> f64 {
    let mut se = 0.0f64;
    let mut n = 0usize;
    for y in border..a.height.saturating_sub(border) {
        for x in border..a.width.saturating_sub(border) {
            let i = 3 * (y * a.width + x);
            for c in 0..3 {
                let d = a.data[i + c] as f64 - b.data[i + c] as f64;
                se += d * d;
                n += 1;
            }
        }
    }
    if n == 0 || se == 0.0 {
        return f64::INFINITY;
    }
    let mse = se / n as f64;
    10.0 * (255.0f64 * 255.0 / mse).log10()
}
