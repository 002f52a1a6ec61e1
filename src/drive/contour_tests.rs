//! Tests of the path frame and the contour controller (`super`).

use super::*;

fn v3(x: f32, y: f32, z: f32) -> PoseVec {
    [x, y, z, 0.0, 0.0]
}

#[test]
fn the_reciprocal_square_root_is_within_a_ten_millionth() {
    for &x in &[1e-6f32, 0.01, 0.5, 1.0, 2.0, 3.0, 100.0, 12_345.0, 1e8] {
        let want = 1.0 / (x as f64).sqrt();
        let got = rsqrt(x) as f64;
        assert!(
            (got / want - 1.0).abs() < 1e-7 * 2.0,
            "{x}: {got} vs {want}"
        );
    }
}

#[test]
fn a_lag_along_a_straight_path_is_no_contour_error() {
    let f = PathFrame::new(&v3(3.0, 4.0, 0.0), &[0.0; POSE_AXES]);
    let eps = f.contour_error(&v3(0.3, 0.4, 0.0));
    assert!(eps.iter().all(|c| c.abs() < 1e-6), "{eps:?}");
    // A sideways error is all contour error, along the normal.
    let eps = f.contour_error(&v3(-0.4, 0.3, 0.2));
    assert!((eps[0] + 0.4).abs() < 1e-6 && (eps[1] - 0.3).abs() < 1e-6);
    assert!((eps[2] - 0.2).abs() < 1e-6);
}

#[test]
fn a_lag_along_a_circle_is_no_contour_error_to_second_order() {
    // Circle of radius 10 mm at 10 mm/s, setpoint at (10, 0) moving +Y; the actual
    // position lags 0.1 rad on the circle.
    let f = PathFrame::new(&v3(0.0, 10.0, 0.0), &v3(-10.0, 0.0, 0.0));
    assert!((f.curvature[0] + 0.1).abs() < 1e-6, "{:?}", f.curvature);
    let y = (10.0 * 0.1f32.cos(), -10.0 * 0.1f32.sin());
    let e = v3(10.0 - y.0, -y.1, 0.0);
    let eps = f.contour_error(&e);
    let plain = e[0]; // the normal part alone: 0.05 mm
    assert!(plain > 0.04);
    assert!(eps[0].abs() < 1e-3 * plain * 10.0, "{eps:?}");
}

#[test]
fn the_curvature_of_a_path_leaving_rest_is_bounded() {
    // 0.02 mm/s after the first tick from rest, the velocity's turn from the
    // previous move read as 20 mm/s² across it: 5·10⁴ /mm, taken as MAX_CURVATURE
    // in the same direction; a 0.1 mm lag then bends by at most ½·0.1²·2 mm.
    let f = PathFrame::new(&v3(0.02, 0.0, 0.0), &v3(0.0, 20.0, 0.0));
    assert!(
        (f.curvature[1] - MAX_CURVATURE).abs() < 1e-5,
        "{:?}",
        f.curvature
    );
    assert!(f.curvature[0].abs() < 1e-6 && f.curvature[2].abs() < 1e-6);
    let eps = f.contour_error(&v3(0.1, 0.0, 0.0));
    assert!((eps[1] - 0.01).abs() < 1e-6, "{eps:?}");
}

#[test]
fn a_normal_acceleration_the_ticks_do_not_resolve_is_no_curvature() {
    // 0.5 mm/s and 3 mm/s² across the path: the targets' rounding, not a radius of
    // 0.08 mm.
    let f = PathFrame::new(&v3(0.5, 0.0, 0.0), &v3(-100.0, 3.0, 0.0));
    assert_eq!(f.curvature, [0.0; POSE_AXES]);
    // From twice RESOLVED_ACCEL in full, between it and that in proportion.
    let f = PathFrame::new(&v3(10.0, 0.0, 0.0), &v3(0.0, 8.0, 0.0));
    assert!((f.curvature[1] - 0.08).abs() < 1e-6, "{:?}", f.curvature);
    let f = PathFrame::new(&v3(10.0, 0.0, 0.0), &v3(0.0, 6.0, 0.0));
    assert!((f.curvature[1] - 0.03).abs() < 1e-6, "{:?}", f.curvature);
}

#[test]
fn a_stop_keeps_the_frame_of_the_ticks_that_resolved_it() {
    // Slowing to a stop along (3, 4, 0)/5, the tool axis held. The last ticks' rates
    // carry the targets' rounding: 1e-3 mm/s across the path, 1e-4 °/s of turn.
    let mut f = PathFrame::default().next(&v3(1.2, 1.6, 0.0), &v3(-60.0, -80.0, 0.0));
    let resolved = f;
    let mut last = [0.0; POSE_AXES];
    for (s, noise) in [(0.5f32, 1e-3f32), (0.1, -1e-3), (0.013, 1e-3)] {
        last = v3(0.6 * s, 0.8 * s + noise, 0.0);
        last[4] = 1e-4;
        f = f.next(&last, &v3(-70.0, -93.0, 0.0));
        assert!(f.moving());
        assert_eq!(
            (f.tangent, f.curvature, f.turn),
            (resolved.tangent, resolved.curvature, resolved.turn)
        );
    }
    // A lag of 10 µm along the path is no contour error and no direction error...
    let lag = [0.006, 0.008, 0.0, 0.0, 0.0];
    let eps = f.contour_error(&lag);
    assert!(eps.iter().all(|c| c.abs() < 1e-8), "{eps:?}");
    // ...where the last tick's own frame (2.5° off the path, 0.0072 °/mm of turn)
    // reads 72 µ° of direction error and 0.4 µm of path error into it.
    let own = PathFrame::new(&last, &v3(-70.0, -93.0, 0.0)).contour_error(&lag);
    assert!(own[4].abs() > 7e-5 && own[0].abs() > 2e-4, "{own:?}");
    // Standing: no frame; a start from rest takes its own frame at once.
    f = f.next(&[0.0; POSE_AXES], &[0.0; POSE_AXES]);
    assert!(!f.moving());
    f = f.next(&v3(0.0, 0.05, 0.0), &v3(0.0, 50.0, 0.0));
    assert!(f.moving() && (f.tangent[1] - 1.0).abs() < 1e-6, "{f:?}");
    // Below RESOLVED_SPEED, a tick as fast as the one before takes its own frame.
    let g = f.next(&v3(0.05, 0.0, 0.0), &[0.0; POSE_AXES]);
    assert!((g.tangent[0] - 1.0).abs() < 1e-6, "{g:?}");
}

#[test]
fn standing_still_there_is_no_contour_error_and_no_coupling() {
    let f = PathFrame::new(&[0.0; POSE_AXES], &[0.0; POSE_AXES]);
    assert!(!f.moving());
    assert_eq!(f.contour_error(&v3(1.0, 1.0, 1.0)), [0.0; POSE_AXES]);
}

fn config(mode: ContourMode) -> ContourConfig {
    ContourConfig {
        mode,
        kp: 10.0,
        ki: 100.0,
        max_integral: 5.0,
        kr: 20.0,
        max_offset: 0.5,
    }
}

#[test]
fn cross_coupling_pushes_each_axis_by_its_direction_cosine() {
    let f = PathFrame::new(&v3(10.0, 0.0, 0.0), &[0.0; POSE_AXES]);
    let mut l = ContourLoop::new(&config(ContourMode::CrossCoupled));
    let c = l.update(&f, &v3(0.0, 0.01, 0.0));
    assert!(c.command[0].abs() < 1e-9 && c.command[2].abs() < 1e-9);
    assert!(
        (c.command[1] - (0.1 + 100.0 * 0.01 * 1e-4)).abs() < 1e-6,
        "{c:?}"
    );
    assert_eq!(c.reference, [0.0; POSE_AXES]);
}

#[test]
fn ccpm_shifts_the_reference_along_the_normal_and_integrates_it() {
    let f = PathFrame::new(&v3(10.0, 0.0, 0.0), &[0.0; POSE_AXES]);
    let mut l = ContourLoop::new(&config(ContourMode::Ccpm));
    let mut c = ContourCorrection::default();
    for _ in 0..100 {
        c = l.update(&f, &v3(0.0, 0.01, 0.0));
    }
    assert!(
        (c.reference[1] - 100.0 * 20.0 * 0.01 * 1e-4).abs() < 1e-6,
        "{c:?}"
    );
    assert_eq!(c.reference[0], 0.0);
    // The offset is clamped.
    for _ in 0..1_000_000 {
        c = l.update(&f, &v3(0.0, 1.0, 0.0));
    }
    assert_eq!(c.reference[1], 0.5);
}

#[test]
fn uncoupled_asks_for_nothing() {
    let f = PathFrame::new(&v3(10.0, 0.0, 0.0), &[0.0; POSE_AXES]);
    let mut l = ContourLoop::new(&config(ContourMode::Uncoupled));
    assert_eq!(
        l.update(&f, &v3(0.0, 1.0, 0.0)),
        ContourCorrection::default()
    );
}
