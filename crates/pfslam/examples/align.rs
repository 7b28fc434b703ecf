use pfslam::stereo::image::*;
fn main() {
    let l = load_rgb_png(std::path::Path::new("/tmp/syn_left.png")).unwrap();
    let r = load_rgb_png(std::path::Path::new("/tmp/syn_right.png")).unwrap();
    let (mut gl, mut gr) = (GrayImage::default(), GrayImage::default());
    l.to_gray_into(&mut gl);
    r.to_gray_into(&mut gr);
    for (u, v) in [
        (300usize, 450usize),
        (600, 450),
        (900, 450),
        (1100, 500),
        (900, 300),
        (300, 300),
    ] {
        let mut best = (f64::MAX, 0i32, 0i32);
        for dy in -6i32..=6 {
            for d in 0i32..130 {
                let mut s = 0.0;
                for j in -7i32..=7 {
                    for i in -7i32..=7 {
                        let a = gl.get((u as i32 + i) as usize, (v as i32 + j) as usize) as f64;
                        let xr = u as i32 + i - d;
                        if xr < 0 {
                            s = f64::MAX;
                            break;
                        }
                        let b = gr.get(xr as usize, (v as i32 + j + dy) as usize) as f64;
                        s += (a - b).powi(2);
                    }
                }
                if s < best.0 {
                    best = (s, d, dy);
                }
            }
        }
        println!(
            "({u},{v}) best d {} dy {} ssd {:.0}",
            best.1, best.2, best.0
        );
    }
}
