use pfslam::stereo::image::*;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let l = load_rgb_png(std::path::Path::new(&a[1])).unwrap();
    let r = load_rgb_png(std::path::Path::new(&a[2])).unwrap();
    let (x0, y0, w, h): (usize, usize, usize, usize) = (
        a[3].parse().unwrap(),
        a[4].parse().unwrap(),
        a[5].parse().unwrap(),
        a[6].parse().unwrap(),
    );
    let mut out = RgbImage::new(2 * w, h);
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                out.data[3 * (y * 2 * w + x) + c] = l.data[3 * ((y0 + y) * l.width + x0 + x) + c];
                out.data[3 * (y * 2 * w + w + x) + c] =
                    r.data[3 * ((y0 + y) * r.width + x0 + x) + c];
            }
        }
    }
    std::fs::write(&a[7], encode_rgb_png(&out).unwrap()).unwrap();
}
