use pfslam::stereo::image::*;
fn main() {
    for kind in 0..4 {
        let (w, h) = (320, 240);
        let mut img = RgbImage::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f64, y as f64);
                let v = match kind {
                    0 => 128.0 + 60.0 * (fx * 0.3).sin() * (fy * 0.2).cos(),
                    1 => 128.0 + 60.0 * (fx * 0.8).sin(),
                    2 => {
                        if (fx - 160.0).hypot(fy - 120.0) < 70.0 {
                            200.0
                        } else {
                            50.0
                        }
                    }
                    _ => 128.0 + 60.0 * (fx * 0.1).sin(),
                };
                let col = [1.0, 0.9, 0.7];
                for c in 0..3 {
                    img.data[3 * (y * w + x) + c] = (v * col[c]) as u8;
                }
            }
        }
        let raw = mosaic(&img, BayerPattern::Bggr);
        let mut out = RgbImage::default();
        for m in [Demosaic::Bilinear, Demosaic::MalvarHeCutler] {
            demosaic_into(&raw, BayerPattern::Bggr, m, &mut out).unwrap();
            println!("kind {kind} {m:?} {:.2}", psnr_db(&img, &out, 2));
        }
    }
}
