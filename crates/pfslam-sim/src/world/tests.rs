use super::*;

#[test]
fn builtins_are_valid() {
    for name in BUILTIN_WORLDS {
        let w = World::builtin(name).unwrap();
        assert!(w.prisms.len() > 20, "{name}");
        assert!(w.route.len() >= 4, "{name}");
        for p in &w.prisms {
            assert!(signed_area(&p.footprint) > 0.0);
        }
    }
    assert!(World::builtin("nope").is_err());
}

#[test]
fn routes_keep_clear_of_obstacles() {
    // the driven path (centre of the vehicle) keeps this far from every footprint
    for (name, radius, clearance) in [("campus", 9.0, 2.5), ("office", 0.6, 0.5)] {
        let w = World::builtin(name).unwrap();
        let path = crate::path::Path::from_route(&w.route, radius).unwrap();
        let mut s = 0.0;
        while s < path.lap_m() {
            let p = path.at(s);
            for pr in &w.prisms {
                let n = pr.footprint.len();
                let d = (0..n)
                    .map(|k| {
                        dist_point_segment(p.x_m, p.y_m, pr.footprint[k], pr.footprint[(k + 1) % n])
                    })
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    !pr.contains_xy(p.x_m, p.y_m) && d >= clearance,
                    "{name}: path at s = {s:.1} ({:.1}, {:.1}) is {d:.2} m from a {}",
                    p.x_m,
                    p.y_m,
                    pr.kind
                );
            }
            s += 0.5;
        }
    }
}

#[test]
fn text_roundtrip() {
    let w = World::builtin("office").unwrap();
    let back = World::parse(&w.to_text(), Path::new("x.world"), "x").unwrap();
    assert_eq!(w, back);
}

#[test]
fn parse_errors_name_line() {
    let text = "name t\nbox wall 0 0 1 1 0 0 2\nprism building 0 5 0 0 1 0\n";
    let e = World::parse(text, Path::new("my.world"), "t")
        .unwrap_err()
        .to_string();
    assert!(e.contains("my.world:3"), "{e}");
    let e = World::parse("route 1 2 3\n", Path::new("r.world"), "r")
        .unwrap_err()
        .to_string();
    assert!(e.contains("r.world:1") && e.contains("odd"), "{e}");
    let e = World::parse("\n\nfoo 1\n", Path::new("f.world"), "f")
        .unwrap_err()
        .to_string();
    assert!(e.contains("f.world:3") && e.contains("foo"), "{e}");
    let e = World::parse("box a 0 0 1 1 0 0 nan\n", Path::new("n.world"), "n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("n.world:1"), "{e}");
}

#[test]
fn ground_texture_layers() {
    let w = World::builtin("campus").unwrap();
    // the campus is shifted by -20 m in x so the car starts at the origin
    assert_eq!(w.route[0], [0.0, 0.0]);
    assert_eq!(w.ground.rgb_at(-20.0, 50.0), [230, 230, 230]); // lane line
    assert_eq!(w.ground.rgb_at(-17.0, 50.0), [60, 60, 64]); // asphalt
    assert_eq!(w.ground.rgb_at(330.0, 60.0), [70, 120, 50]); // park
}
