//! Arc geometry in the plane of an arc: the centre of an R-format arc, and the check that
//! a centre-format arc ends on its circle.
//!
//! Coordinates are in-plane (first, second axis of the plane, see
//! [`crate::gcode::canon::Plane::axes`]), nm, as `f64` (exact for the positions allowed, below
//! 2⁵³ nm).
//!
//! Tolerances:
//! - centre format (I J K), LinuxCNC's rule (`arc_data_ijk`, with its defaults
//!   `CENTER_ARC_RADIUS_TOLERANCE_MM` = 2·0.01·√2 mm, `…_INCH` = 2·0.001·√2 in and
//!   `SPIRAL_RELATIVE_TOLERANCE` = 0.001): the end's distance to the centre may differ
//!   from the start's by at most [`CENTRE_ARC_ABS_NM_MM`] (G21) or
//!   [`CENTRE_ARC_ABS_NM_INCH`] (G20), or by up to 100 times that when it is at most
//!   0.1 % of the larger radius. The controller follows the resulting spiral exactly
//!   (its radius moves linearly), up to a radius change of
//!   [`pkmc::motion::geometry::ARC_RADIUS_SLACK_NM`] (0.08 mm): a larger spiral, which LinuxCNC
//!   accepts, is refused by name.
//! - R format (`Options::arc_tolerance_nm`, default 0.002 mm): the radius may be at most
//!   the tolerance shorter than half the chord (the arc is then taken as a half circle).
//!
//! Source: LinuxCNC's G2/G3 reference and its interpreter's `arc_data_r` (centre of an
//! R-format arc: on the chord's perpendicular bisector, on the right of the chord for a
//! G2 with positive R or a G3 with negative R, i.e. negative R selects the arc longer
//! than a half circle).

use super::ErrorKind;

/// Centre of the arc from `start` to `end` with radius `radius` (negative: the larger
/// arc). Inlined where arcs are made: its result then stays in registers (the
/// interpreter's hot path on programs of R-format arcs).
#[inline(always)]
pub fn centre_from_radius(
    start: [f64; 2],
    end: [f64; 2],
    radius: f64,
    clockwise: bool,
    tolerance: f64,
) -> Result<[f64; 2], (ErrorKind, String)> {
    let (dx, dy) = (end[0] - start[0], end[1] - start[1]);
    let chord = (dx * dx + dy * dy).sqrt();
    if chord == 0.0 {
        return Err(full_circle_by_radius());
    }
    let r = radius.abs();
    let half = chord / 2.0;
    if half - r > tolerance {
        return Err(radius_too_small(r, chord));
    }
    let offset = (r * r - half * half).max(0.0).sqrt();
    // Unit normal to the chord: on its right for G2 with R > 0 (or G3 with R < 0).
    let right = clockwise == (radius > 0.0);
    let (nx, ny) = if right {
        (dy / chord, -dx / chord)
    } else {
        (-dy / chord, dx / chord)
    };
    let mid = [(start[0] + end[0]) / 2.0, (start[1] + end[1]) / 2.0];
    Ok([mid[0] + offset * nx, mid[1] + offset * ny])
}

#[cold]
fn full_circle_by_radius() -> (ErrorKind, String) {
    (
        ErrorKind::InvalidTarget,
        "R-format arc ending where it starts: a full circle needs the centre (I J K)".into(),
    )
}

#[cold]
fn radius_too_small(r: f64, chord: f64) -> (ErrorKind, String) {
    (
        ErrorKind::ArcRadius,
        format!(
            "arc radius {} mm too small to reach the end point ({} mm away)",
            mm(r),
            mm(chord)
        ),
    )
}

/// Checks that `end` lies on the circle about `centre` through `start`, within
/// `tolerance`; a zero radius is an error too.
/// LinuxCNC's absolute tolerance on a centre-format arc's end radius in G21, nm
/// (2·0.01·√2 mm).
pub const CENTRE_ARC_ABS_NM_MM: f64 = 28_284.271;
/// The same in G20, nm (2·0.001·√2 in).
pub const CENTRE_ARC_ABS_NM_INCH: f64 = 71_842.051;
/// LinuxCNC's relative tolerance on it (of the larger radius).
pub const CENTRE_ARC_REL: f64 = 0.001;

/// Checks that a centre-format arc ends on its circle, by LinuxCNC's rule: its end radius
/// may differ from its start radius by at most `abs_tolerance` nm, or by at most 100
/// times that when the difference is at most [`CENTRE_ARC_REL`] of the larger radius.
/// A difference the controller cannot follow (over
/// [`pkmc::motion::geometry::ARC_RADIUS_SLACK_NM`]) is refused by name.
pub fn check_end(
    start: [f64; 2],
    end: [f64; 2],
    centre: [f64; 2],
    abs_tolerance: f64,
) -> Result<(), (ErrorKind, String)> {
    let r0 = dist(start, centre);
    let r1 = dist(end, centre);
    if r0 == 0.0 {
        return Err((
            ErrorKind::ArcRadius,
            "arc with zero radius (its centre is its start point)".into(),
        ));
    }
    let d = (r1 - r0).abs();
    let rel = d / r0.max(r1);
    if d > 100.0 * abs_tolerance || (rel > CENTRE_ARC_REL && d > abs_tolerance) {
        return Err((
            ErrorKind::InvalidTarget,
            format!(
                "arc end is off its circle: start radius {} mm, end radius {} mm \
             (they differ by {} mm, {:.3} % of the radius; at most {} mm, or up to 100 \
             times that within 0.1 % of the radius, are accepted)",
                mm(r0),
                mm(r1),
                mm(d),
                rel * 100.0,
                mm(abs_tolerance)
            ),
        ));
    }
    let slack = pkmc::motion::geometry::ARC_RADIUS_SLACK_NM as f64;
    if d > slack {
        return Err((
            ErrorKind::Unsupported,
            super::unsupported(&format!(
                "spiral arcs whose radius changes by more than {} mm (this one: {} mm, from \
             {} mm to {} mm)",
                mm(slack),
                mm(d),
                mm(r0),
                mm(r1)
            )),
        ));
    }
    Ok(())
}

/// How far a chord of [`chords`] may lie from its arc, nm, before its ends are rounded
/// to whole nanometres (at most 0.87 nm more).
pub const CHORD_SAGITTA_NM: f64 = 40.0;

/// The blending tolerance of the joins between the chords of one arc, nm (the arc's
/// own tolerance, when it is smaller and not exact stop). The compressor may merge the
/// chords into curves within 0.95 of it: 40 + 38 + 0.87 nm stays within
/// [`CHORDS_WITHIN_NM`] of the arc.
pub const CHORD_JOIN_NM: u32 = 40;

/// How far the path of an arc sent as [`chords`] may be from the true arc, nm: 0.1 µm.
pub const CHORDS_WITHIN_NM: f64 = 100.0;

/// An arc block the controller does not run exactly (`pkmc::motion::geometry::Path::checked`
/// refuses it: its radius is above [`pkmc::motion::geometry::MAX_ARC_RADIUS_NM`], its radius
/// changes by more than [`pkmc::motion::geometry::ARC_RADIUS_SLACK_NM`], or its plan misses the
/// controller's numeric checks), from `from`, as straight moves along it: its points
/// at equal steps of angle (the radius moving linearly from the start's to the end's,
/// the helix axis and A B C linearly), each chord within [`CHORD_SAGITTA_NM`] of the
/// arc, ending exactly on its target. Every move has the arc's line and feed; the joins
/// between them blend within [`CHORD_JOIN_NM`], and the last keeps the arc's
/// tolerance. Not an arc: `vec![*arc]`.
pub fn chords(
    arc: &pkmc::motion::block::Block,
    from: &[i64; 6],
) -> Vec<pkmc::motion::block::Block> {
    use pkmc::motion::block::Motion;
    let Motion::Arc {
        center,
        plane,
        clockwise,
        turns,
    } = arc.motion
    else {
        return vec![*arc];
    };
    let (i, j, _) = plane.axes();
    let c = [center[0] as f64, center[1] as f64];
    let s = [from[i] as f64 - c[0], from[j] as f64 - c[1]];
    let e = [arc.target[i] as f64 - c[0], arc.target[j] as f64 - c[1]];
    let (r0, r1) = (s[0].hypot(s[1]), e[0].hypot(e[1]));
    let (a0, a1) = (s[1].atan2(s[0]), e[1].atan2(e[0]));
    let tau = std::f64::consts::TAU;
    // The sweep as the controller's geometry takes it (`Path::new`): in (0, 2π] each
    // way, a full circle when the ends meet, plus the extra turns.
    let wrap = |x: f64| {
        let w = x - (x / tau).floor() * tau;
        if w < 1e-12 {
            tau
        } else {
            w
        }
    };
    let sweep = if clockwise {
        -(wrap(a0 - a1) + tau * turns as f64)
    } else {
        wrap(a1 - a0) + tau * turns as f64
    };
    // A chord spanning δ at radius r lies r·(1 − cos(δ/2)) inside the arc.
    let r = r0.max(r1);
    let step = if r > 2.0 * CHORD_SAGITTA_NM {
        2.0 * (1.0 - CHORD_SAGITTA_NM / r).acos()
    } else {
        std::f64::consts::FRAC_PI_4
    };
    let n = (sweep.abs() / step).ceil().max(1.0) as u64;
    let join = match arc.tolerance_nm {
        0 => CHORD_JOIN_NM,
        t => t.min(CHORD_JOIN_NM),
    };
    let mut out = Vec::with_capacity(n as usize);
    let mut last = *from;
    for k in 1..=n {
        let target = if k == n {
            arc.target
        } else {
            let t = k as f64 / n as f64;
            let (a, rad) = (a0 + sweep * t, r0 + (r1 - r0) * t);
            let mut p = [0i64; 6];
            for (x, (f, to)) in p.iter_mut().zip(from.iter().zip(&arc.target)) {
                *x = f + ((to - f) as f64 * t).round() as i64;
            }
            p[i] = (c[0] + rad * a.cos()).round() as i64;
            p[j] = (c[1] + rad * a.sin()).round() as i64;
            p
        };
        if target == last && k < n {
            continue;
        }
        out.push(pkmc::motion::block::Block {
            motion: Motion::Linear,
            target,
            tolerance_nm: if k == n { arc.tolerance_nm } else { join },
            ..*arc
        });
        last = target;
    }
    out
}

/// Distance between two in-plane points (no overflow: coordinates are below 2⁶³).
fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (a[0] - b[0], a[1] - b[1]);
    (dx * dx + dy * dy).sqrt()
}

/// nm as mm, to the nm, without trailing zeros.
pub(crate) fn mm(nm: f64) -> String {
    let s = format!("{:.6}", nm / 1e6);
    let s = s.trim_end_matches('0');
    s.strip_suffix('.').unwrap_or(s).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: [f64; 2], b: [f64; 2]) -> bool {
        (a[0] - b[0]).abs() < 1e-6 && (a[1] - b[1]).abs() < 1e-6
    }

    #[test]
    fn positive_r_takes_the_short_arc_and_negative_r_the_long_one() {
        // Quarter circle from (10, 0) to (0, 10) about the origin, counter-clockwise.
        let (s, e) = ([10.0, 0.0], [0.0, 10.0]);
        assert!(close(
            centre_from_radius(s, e, 10.0, false, 1.0).unwrap(),
            [0.0, 0.0]
        ));
        // The same ends, counter-clockwise the long way: the centre mirrors.
        assert!(close(
            centre_from_radius(s, e, -10.0, false, 1.0).unwrap(),
            [10.0, 10.0]
        ));
        // Clockwise short arc: the mirrored centre too.
        assert!(close(
            centre_from_radius(s, e, 10.0, true, 1.0).unwrap(),
            [10.0, 10.0]
        ));
    }

    #[test]
    fn a_radius_just_short_of_half_the_chord_is_a_half_circle() {
        let c = centre_from_radius([0.0, 0.0], [20.0, 0.0], 9.999, true, 0.002).unwrap();
        assert!(close(c, [10.0, 0.0]));
        assert!(centre_from_radius([0.0, 0.0], [20.0, 0.0], 9.99, true, 0.002).is_err());
    }

    #[test]
    fn an_end_within_linuxcnc_s_tolerances_is_accepted_and_one_beyond_either_is_not() {
        // 4 µm on a 10 mm radius (an inch post's rounding): accepted, as by LinuxCNC.
        assert!(check_end(
            [10e6, 0.0],
            [0.0, 10.004e6],
            [0.0, 0.0],
            CENTRE_ARC_ABS_NM_MM
        )
        .is_ok());
        // LinuxCNC's own bad-arc tests: 28.57 µm on 25 mm (over the absolute part) and
        // 2.857 mm on 3000 mm (0.095 %, but far over the absolute part).
        assert!(check_end(
            [0.0, 0.0],
            [50e6, 0.0],
            [24.9857e6, 0.0],
            CENTRE_ARC_ABS_NM_MM
        )
        .is_err());
        assert!(check_end(
            [0.0, 0.0],
            [6000e6, 0.0],
            [3001.4284e6, 0.0],
            CENTRE_ARC_ABS_NM_MM
        )
        .is_err());
        // 20 µm on 5 mm: within the absolute part, so accepted although over 0.1 % (as
        // LinuxCNC's good-arc tests show); 40 µm on 5 mm is over both.
        assert!(check_end([5e6, 0.0], [0.0, 5.02e6], [0.0, 0.0], CENTRE_ARC_ABS_NM_MM).is_ok());
        assert!(check_end([5e6, 0.0], [0.0, 5.04e6], [0.0, 0.0], CENTRE_ARC_ABS_NM_MM).is_err());
        // 1 mm on 1000 mm (0.1 %): LinuxCNC accepts it; the controller cannot follow a
        // spiral that large, so it is refused by name.
        let e = check_end(
            [1000e6, 0.0],
            [0.0, 1001e6],
            [0.0, 0.0],
            CENTRE_ARC_ABS_NM_MM,
        )
        .map_err(|(_, message)| message);
        assert!(e.unwrap_err().starts_with("unsupported: spiral arcs"));
    }

    #[test]
    fn an_arc_of_16_m_over_35_6_mm_is_16_chords_within_40_nm_ending_on_its_target() {
        use pkmc::motion::block::{Block, Motion, Plane};
        // G2 X35.6 Y0 I17.8 J-16275.9903 from the origin (issue 34).
        let arc = Block {
            line: 3,
            motion: Motion::Arc {
                center: [17_800_000, -16_275_990_300],
                plane: Plane::Xy,
                clockwise: true,
                turns: 0,
            },
            target: [35_600_000, 0, 0, 0, 0, 0],
            feed: 50_000_000,
            tolerance_nm: 0,
        };
        assert!(pkmc::motion::geometry::Path::checked(&arc, &[0; 6]).is_err());
        let c = chords(&arc, &[0; 6]);
        assert_eq!(c.len(), 16);
        assert_eq!(c.last().unwrap().target, arc.target);
        let r = 17.8e6f64.hypot(16_275_990_300.0);
        let mut from = [0.0f64, 0.0];
        for b in &c {
            assert_eq!((b.motion, b.line, b.feed), (Motion::Linear, 3, 50_000_000));
            let to = [b.target[0] as f64, b.target[1] as f64];
            // The chord's midpoint lies inside the circle by at most 40 nm (+ rounding).
            let mid = [(from[0] + to[0]) / 2.0, (from[1] + to[1]) / 2.0];
            let inside = r - (mid[0] - 17.8e6).hypot(mid[1] + 16_275_990_300.0);
            assert!((-1.0..=41.0).contains(&inside), "{inside} nm");
            from = to;
        }
        // The joins blend within 40 nm under G61; the last keeps the arc's exact stop.
        assert_eq!(c[0].tolerance_nm, CHORD_JOIN_NM);
        assert_eq!(c.last().unwrap().tolerance_nm, 0);
    }

    #[test]
    fn an_end_off_the_circle_is_reported_in_mm() {
        let (_, e) = check_end([5e6, 0.0], [0.0, 5.1e6], [0.0, 0.0], 2000.0).unwrap_err();
        assert!(e.contains("start radius 5 mm, end radius 5.1 mm"), "{e}");
    }
}
