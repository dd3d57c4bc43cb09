//! The embedded garment library: every garment loads and binds to the template's skeleton, sits
//! on the skin, follows body shapes through its base-mesh binding, and covers the skin it
//! dresses.

use glam::Vec3;
use lhmpp::body::garment::report::fit_report;
use lhmpp::body::{BodyTemplate, GarmentKind, GarmentLibrary, MakeHumanShape};

fn load() -> (GarmentLibrary, BodyTemplate) {
    let template = BodyTemplate::load_default().unwrap();
    let library = GarmentLibrary::load_default().unwrap();
    library.validate(&template, "embedded").unwrap();
    (library, template)
}

#[test]
fn every_garment_binds_to_the_template_skeleton() {
    let (library, template) = load();
    assert_eq!(library.garments.len(), 44);
    for kind in GarmentKind::ALL {
        assert!(!library.of_kind(kind).is_empty(), "no {}", kind.name());
    }
    for g in &library.garments {
        for (b, w) in g.skin.bones.iter().zip(&g.skin.weights) {
            assert!(
                (w.iter().sum::<f32>() - 1.0).abs() < 1e-5,
                "{}: {w:?}",
                g.name
            );
            for (bone, weight) in b.iter().zip(w) {
                if *weight > 0.0 {
                    assert!((*bone as usize) < template.skeleton.len(), "{}", g.name);
                }
            }
        }
    }
    let names: Vec<&str> = library.garments.iter().map(|g| g.name.as_str()).collect();
    for name in [
        "long_coat",
        "dress",
        "skirt",
        "shorts",
        "bob01",
        "fedora01",
        "shoes01",
    ] {
        assert!(names.contains(&name), "{name} missing");
    }
}

#[test]
fn garments_sit_on_the_skin_and_hanging_ones_stand_off() {
    let (library, template) = load();
    let anchors = template.sample_anchors(4096, 1);
    let fits = fit_report(&library, &template, &anchors, 4000);
    for f in &fits {
        let kind = library.garments[library.index_of(&f.name).unwrap()].kind;
        // Fitted garments: a few millimetres to 3 cm off the skin (MakeHuman's fits measured
        // 9–16 mm median); hanging ones (skirts, coat tails, long hair) further.
        assert!(f.skin_median > 0.002 && f.skin_median < 0.05, "{f:?}");
        if kind != GarmentKind::Hair && !["long_coat", "dress", "skirt"].contains(&f.name.as_str())
        {
            assert!(f.skin_p95 < 0.1, "{f:?}");
            assert!(f.reach[1] > 0.85, "{f:?}");
        }
        assert!(f.reach[0] <= f.reach[1] && f.reach[1] <= f.reach[2]);
        assert!(f.covered > 0.005, "{f:?}");
    }
    let skirt = fits.iter().find(|f| f.name == "skirt").unwrap();
    assert!(skirt.skin_p95 > 0.08 && skirt.reach[0] < 0.2, "{skirt:?}");
}

#[test]
fn refitting_on_a_shaped_base_equals_scaling_the_rest_vertices() {
    let (library, template) = load();
    let shape = MakeHumanShape {
        height_scale: 1.07,
        girth_scale: 0.9,
    };
    let shaped = shape.shaped(&template);
    let mut checked = 0;
    for g in &library.garments {
        let expected = g.shaped_vertices(&shape);
        let base_bound: Vec<usize> = (0..g.vertices.len())
            .filter(|&i| {
                g.binding.vertices[i]
                    .iter()
                    .all(|&v| (v as usize) < template.vertices.len())
            })
            .collect();
        for &i in &base_bound {
            // Vertices bound to skin vertices refit on the shaped template; they must land
            // where scaling puts them (f16 storage: about a millimetre). Helper-bound vertices
            // have no template vertex to refit on.
            let b = &g.binding;
            let mut r = b.offsets[i] * shape.axis_scale();
            for k in 0..3 {
                r += shaped.vertices[b.vertices[i][k] as usize] * b.weights[i][k];
            }
            assert!(
                r.distance(expected[i]) < 2.5e-3,
                "{} vertex {i}: {r} vs {}",
                g.name,
                expected[i]
            );
            checked += 1;
        }
    }
    assert!(checked > 20_000, "{checked} vertices checked");
}

#[test]
fn posed_garments_stay_on_the_skin_they_hang_on() {
    let (library, template) = load();
    let pose = lhmpp::body::motion::walk_pose(10.0);
    let matrices = template.skeleton.try_skinning_matrices(&pose).unwrap();
    let body = template.skin.skin_points(&template.vertices, &matrices);
    let grid = lhmpp::body::PointGrid::for_surface(&template.vertices);
    for g in &library.garments {
        let posed = g.skin.skin_points(&g.vertices, &matrices);
        let mut change: Vec<f32> = g
            .vertices
            .iter()
            .zip(&posed)
            .map(|(v, p)| {
                let n = grid.nearest(*v).unwrap();
                (p.distance(body[n]) - v.distance(template.vertices[n])).abs()
            })
            .collect();
        change.sort_by(f32::total_cmp);
        let (median, p95) = (change[change.len() / 2], change[change.len() * 95 / 100]);
        println!(
            "{}: median {:.1} mm, p95 {:.1} mm",
            g.name,
            median * 1e3,
            p95 * 1e3
        );
        assert!(median < 0.01 && p95 < 0.05, "{}: {median} {p95}", g.name);
    }
}

#[test]
fn garments_cover_the_skin_they_dress() {
    let (library, template) = load();
    let nearest = |p: Vec3| {
        (0..template.vertices.len())
            .min_by(|a, b| {
                template.vertices[*a]
                    .distance_squared(p)
                    .total_cmp(&template.vertices[*b].distance_squared(p))
            })
            .unwrap()
    };
    let chest = nearest(Vec3::new(0.0, 1.25, 0.2));
    let shin = nearest(Vec3::new(0.17, 0.3, 0.1));
    let crown = nearest(Vec3::new(0.0, 1.7, 0.0));
    let sole = nearest(Vec3::new(0.22, 0.0, 0.0));
    let covers = |name: &str, v: usize| library.garments[library.index_of(name).unwrap()].covers[v];
    assert!(covers("male_casualsuit02.top", chest));
    assert!(!covers("male_casualsuit02.top", shin));
    assert!(covers("male_casualsuit02.bottom", shin));
    assert!(!covers("male_casualsuit02.bottom", chest));
    assert!(!covers("skirt", crown) && !covers("shorts", shin));
    assert!(covers("long_coat", chest));
    assert!(covers("short02", crown) && covers("fedora01", crown));
    assert!(covers("shoes01", sole));
}
