//! Corner blends: tangent-continuous, within P of the programmed polyline, only
//! where the program blends within a tolerance and only in X Y Z.

use super::super::{compress, compress_runs};
use super::*;

const P: u32 = 100_000; // G64 P0.1

fn g1(x: f64, y: f64, line: u32, tol: u32) -> Block {
    Block {
        line,
        motion: Motion::Linear,
        target: [
            (x * 1e6).round() as i64,
            (y * 1e6).round() as i64,
            0,
            0,
            0,
            0,
        ],
        feed: 50_000_000,
        tolerance_nm: tol,
    }
}

/// The streamed blocks' geometry (from `start`), each sampled finely.
fn samples(c: &Compressed, start: [i64; AXES]) -> Vec<V> {
    let mut from = start;
    let mut out = vec![];
    for b in &c.blocks {
        if let Some(g) = Geo::of(b, &from) {
            out.extend((0..=200).map(|k| g.at(k as f64 / 200.0)));
        }
        from = b.target;
    }
    out
}

/// Largest distance of the streamed path from the programmed polyline, nm.
fn deviation(programmed: &[Block], c: &Compressed, start: [i64; AXES]) -> f64 {
    let mut pts = vec![to_fit(&start)];
    pts.extend(programmed.iter().map(|b| to_fit(&b.target)));
    samples(c, start)
        .iter()
        .map(|q| to_polyline(q, &pts).0)
        .fold(0.0, f64::max)
}

/// Largest angle, degrees, between the end direction of each block and the start
/// direction of the next.
fn largest_turn(c: &Compressed, start: [i64; AXES]) -> f64 {
    let mut from = start;
    let mut ends = vec![];
    for b in &c.blocks {
        let g = Geo::of(b, &from).unwrap();
        ends.push((unit(&g.deriv(0.0)), unit(&g.deriv(1.0))));
        from = b.target;
    }
    ends.windows(2)
        .map(|w| dot(&w[0].1, &w[1].0).clamp(-1.0, 1.0).acos().to_degrees())
        .fold(0.0, f64::max)
}

/// Two straight legs of 10 mm turning by `turn` degrees at (10, 0).
fn corner(turn: f64, tol: u32) -> Vec<Block> {
    let r = turn.to_radians();
    vec![
        g1(10.0, 0.0, 1, tol),
        g1(10.0 + 10.0 * r.cos(), 10.0 * r.sin(), 2, tol),
    ]
}

#[test]
fn a_corner_between_lines_is_blended_tangentially_within_p() {
    let s = Settings::default();
    for turn in [90.0, 150.0] {
        let p = corner(turn, P);
        let c = compress(&p, [0; AXES], &s);
        let kinds: Vec<_> = c
            .blocks
            .iter()
            .map(|b| b.motion == Motion::Linear)
            .collect();
        assert_eq!(kinds, [true, false, true], "{turn}°: line, blend, line");
        assert_eq!(
            c.blocks[2].target, p[1].target,
            "{turn}°: ends where programmed"
        );
        assert!(largest_turn(&c, [0; AXES]) < 0.01, "{turn}°: tangent");
        let dev = deviation(&p, &c, [0; AXES]);
        // Within P, and not needlessly small: the corner's speed grows with the blend.
        assert!(dev <= P as f64 * s.fit_share, "{turn}°: {dev} nm");
        assert!(dev > 0.5 * P as f64 * s.fit_share, "{turn}°: only {dev} nm");
        // The blend carries the line of the move ending at the corner, and the
        // chords it spans.
        assert_eq!(c.blocks[1].line, 1);
        assert_eq!(
            (
                c.source[0].clone(),
                c.source[1].clone(),
                c.source[2].clone()
            ),
            (0..1, 0..2, 1..2)
        );
    }
}

/// Chords of 0.2 mm along a quarter circle of radius 20 mm, then a sharp turn into
/// another quarter circle: two merged curves meeting at a corner.
fn arcs() -> Vec<Block> {
    let mut out = vec![];
    let n = 157;
    for k in 1..=n {
        let a = k as f64 / n as f64 * std::f64::consts::FRAC_PI_2;
        out.push(g1(20.0 * a.sin(), 20.0 - 20.0 * a.cos(), k, P));
    }
    // From (20, 20) on, leaving at 90° to the arriving direction.
    for k in 1..=n {
        let a = k as f64 / n as f64 * std::f64::consts::FRAC_PI_2;
        out.push(g1(20.0 + 20.0 * a.sin(), 40.0 - 20.0 * a.cos(), n + k, P));
    }
    out
}

#[test]
fn a_corner_between_curves_is_blended_tangentially_within_p() {
    let s = Settings::default();
    let p = arcs();
    let runs = compress_runs(&p, [0; AXES], &s);
    let c = compress(&p, [0; AXES], &s);
    assert!(runs
        .blocks
        .iter()
        .all(|b| matches!(b.motion, Motion::Cubic { .. })));
    assert!(
        largest_turn(&runs, [0; AXES]) > 80.0,
        "the runs meet at a corner"
    );
    assert_eq!(c.blocks.len(), runs.blocks.len() + 1, "one blend");
    assert!(largest_turn(&c, [0; AXES]) < 0.05);
    let dev = deviation(&p, &c, [0; AXES]);
    assert!(dev <= P as f64 * s.fit_share, "{dev} nm");
    assert_eq!(c.blocks.last().unwrap().target, p.last().unwrap().target);
}

#[test]
fn in_g64_without_p_a_corner_is_blended_within_the_g64_tolerance() {
    let s = Settings::default();
    let g64 = s.g64_tolerance_nm * s.fit_share;
    for turn in [4.5, 90.0] {
        let p = corner(turn, u32::MAX);
        let c = compress(&p, [0; AXES], &s);
        assert_eq!(c.blocks.len(), 3, "{turn}°: line, blend, line");
        assert!(matches!(c.blocks[1].motion, Motion::Cubic { .. }));
        assert_eq!(c.blocks[1].tolerance_nm, u32::MAX, "{turn}°: still G64");
        assert!(largest_turn(&c, [0; AXES]) < 0.01, "{turn}°: tangent");
        let dev = deviation(&p, &c, [0; AXES]);
        assert!(dev <= g64, "{turn}°: {dev} nm");
        assert!(dev > 0.5 * g64, "{turn}°: only {dev} nm");
    }
    // `--g64-tolerance 0` merges nothing and blends nothing in G64 without P.
    let exact = Settings {
        g64_tolerance_nm: 0.0,
        ..s
    };
    let p = corner(90.0, u32::MAX);
    assert_eq!(compress(&p, [0; AXES], &exact).blocks, p);
}

#[test]
fn no_blend_in_g61_nor_where_a_b_c_move() {
    let s = Settings::default();
    let p = corner(90.0, 0);
    assert_eq!(compress(&p, [0; AXES], &s).blocks, p, "G61");
    let mut p = corner(90.0, P);
    p[1].target[3] = 5_000_000; // A moves in the second
    assert_eq!(compress(&p, [0; AXES], &s).blocks, p);
    // A turn below the least is left as it is (lines too long to merge); with blends
    // off, nothing is blended.
    let p = corner(0.2, P);
    let lines = Settings {
        max_chord_nm: 1e3,
        ..s
    };
    assert_eq!(compress(&p, [0; AXES], &lines).blocks, p);
    let p = corner(0.6, P);
    assert_eq!(compress(&p, [0; AXES], &lines).blocks.len(), 3);
    let off = Settings { blend: false, ..s };
    let p = corner(90.0, P);
    assert_eq!(compress(&p, [0; AXES], &off).blocks, p);
    // A dwell between the moves leaves the corner alone.
    let mut p = corner(90.0, P);
    p.insert(
        1,
        Block {
            motion: Motion::Dwell(100),
            target: p[0].target,
            ..p[0]
        },
    );
    assert_eq!(compress(&p, [0; AXES], &s).blocks, p);
}

#[test]
fn blending_in_pieces_is_blending_at_once() {
    let s = Settings::default();
    let mut p = arcs();
    p.extend(corner(150.0, P).iter().map(|b| Block {
        target: [
            b.target[0] + 40_000_000,
            b.target[1] + 40_000_000,
            0,
            0,
            0,
            0,
        ],
        ..*b
    }));
    let whole = compress(&p, [0; AXES], &s);
    let runs = compress_runs(&p, [0; AXES], &s);
    assert!(
        whole.blocks.len() >= runs.blocks.len() + 3,
        "blends: {}",
        whole.blocks.len()
    );
    for cut in 1..runs.blocks.len() {
        let mut b = Blender::new(&s, [0; AXES]);
        let mut out = Compressed::default();
        for part in [0..cut, cut..runs.blocks.len()] {
            let piece = Compressed {
                blocks: runs.blocks[part.clone()].to_vec(),
                source: runs.source[part].to_vec(),
            };
            b.push(&p, &piece, 0, &mut out);
        }
        b.finish(&mut out);
        assert_eq!(out, whole, "cut at {cut}");
    }
}

/// |dP/du| over its largest along the block (as the controller runs it) at its start
/// and its end, for each streamed block from `start`.
fn end_ratios(c: &Compressed, start: [i64; AXES]) -> Vec<(f64, f64)> {
    let mut from = start;
    let mut out = vec![];
    for b in &c.blocks {
        let g = Geo::of(b, &from).unwrap();
        let most = (0..=400)
            .map(|k| norm(&g.deriv(k as f64 / 400.0)))
            .fold(0.0, f64::max);
        out.push((norm(&g.deriv(0.0)) / most, norm(&g.deriv(1.0)) / most));
        from = b.target;
    }
    out
}

#[test]
fn a_blend_meets_a_curve_at_the_speed_the_curve_starts_once_its_end_is_trimmed_too() {
    // A line, a curve fastest at its end (turning 45° from the line), and a line
    // turning 60° from the curve: both of the curve's ends are trimmed, the end taking
    // its fastest part. The speed must not jump where the first blend meets it.
    let tol = 1_000_000; // G64 P1
    let mm = |x: f64| (x * 1e6).round() as i64;
    let curve = Block {
        line: 2,
        motion: Motion::Cubic {
            c1: [mm(0.3), mm(0.3), 0, 0, 0, 0],
            c2: [mm(-6.0), mm(-1.5), 0, 0, 0, 0],
        },
        target: [mm(20.0), mm(5.0), 0, 0, 0, 0],
        feed: 50_000_000,
        tolerance_nm: tol,
    };
    let p = vec![g1(10.0, 0.0, 1, tol), curve, g1(20.0, 15.0, 3, tol)];
    let c = compress(&p, [0; AXES], &Settings::default());
    let kinds: Vec<_> = c.blocks.iter().map(|b| b.line).collect();
    assert_eq!(kinds, [1, 1, 2, 2, 3], "line, blend, curve, blend, line");
    let r = end_ratios(&c, [0; AXES]);
    for k in 1..r.len() {
        let jump = (r[k].0 - r[k - 1].1).abs();
        assert!(
            jump < 0.005,
            "blocks {} and {k} meet at |dP/ds| {:.4} and {:.4}",
            k - 1,
            r[k - 1].1,
            r[k].0
        );
    }
}

/// Compressor settings with a machine's figures: 1000 mm/s², 100 mm/s.
fn with_machine() -> Settings {
    Settings {
        accel: 1e9,
        max_speed: 1e8,
        ..Settings::default()
    }
}

/// A straight cubic along X at F3000 from the previous block's end to `x` mm, with
/// its inner control points `c1` after its start and `c2` before its end (mm).
fn straight_x(line: u32, (c1, c2): (f64, f64), x: f64, tol: u32) -> Block {
    let mm = |x: f64| (x * 1e6).round() as i64;
    Block {
        line,
        motion: Motion::Cubic {
            c1: [mm(c1), 0, 0, 0, 0, 0],
            c2: [mm(c2), 0, 0, 0, 0, 0],
        },
        target: [mm(x), 0, 0, 0, 0, 0],
        feed: 50_000_000,
        tolerance_nm: tol,
    }
}

/// The NC lines of the streamed blocks.
fn lines_of(c: &Compressed) -> Vec<u32> {
    c.blocks.iter().map(|b| b.line).collect()
}

#[test]
fn a_junction_that_does_not_turn_is_blended_where_the_speed_over_the_path_speed_jumps() {
    // A straight curve along X whose |dP/du| falls from 10.2 at its start to 9.9 at
    // its end, then a line on along X: no turn, but where they meet the tool's speed
    // over the path speed would jump by 3 %, which holds the junction to 17 mm/s at
    // 1000 mm/s² (v·jump ≤ a·T/2). At F3000 it is blended, and the speed is
    // continuous; at F60, where the jump lets the junction pass at the feed, it is
    // left as it is.
    let tol = 10_000; // G64 P0.01
    let s = with_machine();
    let program = |feed: i64| {
        vec![
            Block {
                feed,
                ..straight_x(1, (3.4, -3.3), 10.0, tol)
            },
            Block {
                feed,
                ..g1(20.0, 0.0, 2, tol)
            },
        ]
    };
    let p = program(50_000_000);
    let before = end_ratios(
        &Compressed {
            blocks: p.clone(),
            source: vec![0..1, 1..2],
        },
        [0; AXES],
    );
    assert!((before[0].1 - before[1].0).abs() > 0.025, "{before:?}");
    let c = compress(&p, [0; AXES], &s);
    let lines = lines_of(&c);
    assert_eq!(lines, [1, 1, 2], "curve, blend, line");
    assert!(largest_turn(&c, [0; AXES]) < 0.01);
    let r = end_ratios(&c, [0; AXES]);
    for k in 1..r.len() {
        assert!((r[k].0 - r[k - 1].1).abs() < 0.005, "{r:?}");
    }
    assert!(deviation(&p, &c, [0; AXES]) <= tol as f64 * s.fit_share);
    let slow = program(1_000_000);
    assert_eq!(compress(&slow, [0; AXES], &s).blocks, slow);
}

#[test]
fn a_junction_is_blended_once_the_next_corner_trims_away_the_fastest_part_after_it() {
    // Two straight curves along X that meet at one |dP/ds|, 0.75 (|dP/du| 12 → 9 over
    // the first, 9 → 12 over the second), and a line turning 90° after the second.
    // The 90° corner's blend trims the second curve's end, its fastest part, so its
    // part as streamed starts at a higher |dP/ds| than the first ends at: a jump that
    // the junction did not have when it was first looked at. The first curve waits,
    // and the junction is blended once the trim is known; the speed is continuous at
    // every join. Without that second look this fails (the jump is over 1 %).
    let tol = 100_000; // G64 P0.1
    let s = with_machine();
    let p = vec![
        straight_x(1, (4.0, -3.0), 10.0, tol),
        straight_x(2, (3.0, -4.0), 20.0, tol),
        g1(20.0, 10.0, 3, tol),
    ];
    let written = end_ratios(
        &Compressed {
            blocks: p.clone(),
            source: vec![0..1, 1..2, 2..3],
        },
        [0; AXES],
    );
    assert!((written[0].1 - written[1].0).abs() < 1e-9, "{written:?}");
    let c = compress(&p, [0; AXES], &s);
    let lines = lines_of(&c);
    assert_eq!(lines, [1, 1, 2, 2, 3], "curve, blend, curve, blend, line");
    let r = end_ratios(&c, [0; AXES]);
    for k in 1..r.len() {
        assert!((r[k].0 - r[k - 1].1).abs() < 0.002, "join {k}: {r:?}");
    }
    assert!(largest_turn(&c, [0; AXES]) < 0.01);
    assert!(deviation(&p, &c, [0; AXES]) <= tol as f64 * s.fit_share);
}

#[test]
fn a_turn_under_the_least_angle_is_blended_where_it_would_take_the_acceleration_at_the_feed() {
    // Two lines turning 0.3° (under `blend_min_deg`). At F3000 on 1000 mm/s² the
    // planner would take about a quarter of the acceleration from both lines to pass
    // it at the feed (ρ = θ·F/(a·T)); it is blended. At F60 it takes 0.5 %, and it is
    // left as it is.
    let tol = 10_000; // G64 P0.01
    let s = with_machine();
    assert!(s.blend_min_deg > 0.3);
    let th = 0.3f64.to_radians();
    let program = |feed| {
        [
            g1(10.0, 0.0, 1, tol),
            g1(10.0 + 10.0 * th.cos(), 10.0 * th.sin(), 2, tol),
        ]
        .map(|b| Block { feed, ..b })
        .to_vec()
    };
    let fast = program(50_000_000);
    let c = compress(&fast, [0; AXES], &s);
    let lines = lines_of(&c);
    assert_eq!(lines, [1, 1, 2], "line, blend, line");
    assert!(largest_turn(&c, [0; AXES]) < 0.01);
    assert!(deviation(&fast, &c, [0; AXES]) <= tol as f64 * s.fit_share);
    let slow = program(1_000_000);
    assert_eq!(compress(&slow, [0; AXES], &s).blocks, slow);
}
