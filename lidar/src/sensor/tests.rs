use super::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// A lidar of `beams` beams all around, exact, of range 0.1..8 m, at the robot's centre.
fn exact(beams: usize) -> Lidar {
    Lidar {
        beams,
        fov_rad: TAU,
        range_min_m: 0.1,
        range_max_m: 8.0,
        noise_std_m: 0.0,
        dropout: 0.0,
        offset: [0.0; 3],
    }
}

/// The beam of `lidar` closest to `angle` from its heading.
fn beam_at(lidar: &Lidar, angle: f64) -> usize {
    let (first, step) = lidar.angles();
    ((angle - first) / step).round() as usize % lidar.beams
}

fn scan(lidar: &Lidar, pose: [f64; 3], discs: &[Disc], seed: u64) -> Vec<f32> {
    let mut ranges = vec![0.0; lidar.beams];
    lidar.scan(
        pose,
        discs,
        &mut ChaCha8Rng::seed_from_u64(seed),
        &mut ranges,
    );
    ranges
}

#[test]
fn a_ray_meets_a_disc_at_its_edge_misses_one_beside_or_behind_it_and_is_at_0_inside() {
    let disc = ([5.0, 0.0], 1.0);
    assert_eq!(ray_to_disc([0.0, 0.0], [1.0, 0.0], &disc), Some(4.0));
    assert_eq!(ray_to_disc([0.0, 0.0], [0.0, 1.0], &disc), None);
    assert_eq!(ray_to_disc([0.0, 0.0], [-1.0, 0.0], &disc), None);
    assert_eq!(ray_to_disc([5.5, 0.0], [1.0, 0.0], &disc), Some(0.0));
    // Tangent: the ray grazes the disc's edge at the closest approach.
    let grazing = ray_to_disc([0.0, 1.0], [1.0, 0.0], &disc).unwrap();
    assert!((grazing - 5.0).abs() < 1e-9);
}

#[test]
fn the_beams_split_a_full_circle_evenly_and_span_a_partial_view_edge_to_edge() {
    let (first, step) = exact(360).angles();
    assert!((first + PI).abs() < 1e-12 && (step - TAU / 360.0).abs() < 1e-12);
    let front = Lidar {
        fov_rad: PI,
        ..exact(181)
    };
    let (first, step) = front.angles();
    assert!((first + FRAC_PI_2).abs() < 1e-12);
    assert!((first + 180.0 * step - FRAC_PI_2).abs() < 1e-12);
}

#[test]
fn a_nearer_disc_hides_a_farther_one_and_only_where_it_stands_in_the_way() {
    let lidar = exact(360);
    // Robot at (1, 1) heading +y: "ahead" is +y in the world.
    let pose = [1.0, 1.0, FRAC_PI_2];
    let near = ([1.0, 4.0], 0.5);
    let far = ([1.0, 7.0], 2.0);
    let ranges = scan(&lidar, pose, &[far, near], 1);
    assert!((ranges[beam_at(&lidar, 0.0)] - 2.5).abs() < 1e-5);
    // 15 degrees to the left the near disc is passed by, the far one is met.
    let left = 15f64.to_radians();
    let expected = ray_to_disc([1.0, 1.0], [-(left.sin()), left.cos()], &far).unwrap();
    assert!((f64::from(ranges[beam_at(&lidar, left)]) - expected).abs() < 1e-5);
    // Behind the robot nothing is within range.
    assert_eq!(ranges[beam_at(&lidar, PI)], f32::INFINITY);
}

#[test]
fn what_is_beyond_the_range_is_infinite_and_what_is_too_near_negative_infinite() {
    let lidar = exact(4);
    let beyond = scan(&lidar, [0.0; 3], &[([9.5, 0.0], 1.0)], 1);
    assert_eq!(beyond[beam_at(&lidar, 0.0)], f32::INFINITY);
    let touching = scan(&lidar, [0.0; 3], &[([0.55, 0.0], 0.5)], 1);
    assert_eq!(touching[beam_at(&lidar, 0.0)], f32::NEG_INFINITY);
}

#[test]
fn the_lidar_ranges_from_where_it_sits_on_the_robot_and_looks_where_it_is_turned() {
    // 0.2 m forward of the centre, turned to the robot's left.
    let lidar = Lidar {
        offset: [0.2, 0.0, FRAC_PI_2],
        ..exact(360)
    };
    // Robot at the origin heading +x; a disc 3 m to its left, one 5 m ahead.
    let ranges = scan(&lidar, [0.0; 3], &[([0.2, 3.0], 0.5), ([5.0, 0.0], 1.0)], 1);
    assert!((ranges[beam_at(&lidar, 0.0)] - 2.5).abs() < 1e-5, "left");
    assert!(
        (ranges[beam_at(&lidar, -FRAC_PI_2)] - 3.8).abs() < 1e-5,
        "ahead"
    );
}

#[test]
fn noise_and_dropouts_follow_their_settings_and_the_seed() {
    let lidar = Lidar {
        noise_std_m: 0.01,
        dropout: 0.1,
        ..exact(1440)
    };
    // A ring of small discs 5 m around the robot: most beams meet one.
    let discs: Vec<Disc> = (0..720)
        .map(|k| {
            let a = TAU * k as f64 / 720.0;
            ([5.0 * a.cos(), 5.0 * a.sin()], 0.05)
        })
        .collect();
    let first = scan(&lidar, [0.0; 3], &discs, 7);
    assert_eq!(
        first.iter().map(|r| r.to_bits()).collect::<Vec<_>>(),
        scan(&lidar, [0.0; 3], &discs, 7)
            .iter()
            .map(|r| r.to_bits())
            .collect::<Vec<_>>(),
        "the same seed gives the same scan"
    );
    let dropped = first.iter().filter(|r| r.is_nan()).count() as f64 / 1440.0;
    assert!((dropped - 0.1).abs() < 0.03, "dropout {dropped}");
    // The exact scan, for the error of every beam that hit a disc.
    let truth = scan(&exact(1440), [0.0; 3], &discs, 7);
    let errors: Vec<f64> = (first.iter().zip(&truth))
        .filter(|(r, t)| r.is_finite() && t.is_finite())
        .map(|(r, t)| f64::from(r - t))
        .collect();
    assert!(errors.len() > 500, "{} beams hit", errors.len());
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    let std = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt();
    assert!(
        mean.abs() < 0.002 && (std - 0.01).abs() < 0.002,
        "mean {mean}, std {std}"
    );
}
