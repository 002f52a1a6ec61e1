//! Arc geometry in the plane of an arc: the centre of an R-format arc, and the check that
//! a centre-format arc ends on its circle.
//!
//! Coordinates are in-plane (first, second axis of the plane, see
//! [`crate::canon::Plane::axes`]), nm, as `f64` (exact for the positions allowed, below
//! 2⁵³ nm).
//!
//! Tolerance (one number, `Options::arc_tolerance_nm`, default 0.002 mm):
//! - centre format (I J K): the end's distance to the centre may differ from the start's
//!   by at most the tolerance. LinuxCNC also accepts up to 0.1 % of the radius; this
//!   interpreter does not, so that the controller never has to absorb a spiral larger
//!   than the tolerance.
//! - R format: the radius may be at most the tolerance shorter than half the chord (the
//!   arc is then taken as a half circle).
//!
//! Source: LinuxCNC's G2/G3 reference and its interpreter's `arc_data_r` (centre of an
//! R-format arc: on the chord's perpendicular bisector, on the right of the chord for a
//! G2 with positive R or a G3 with negative R, i.e. negative R selects the arc longer
//! than a half circle).

/// Centre of the arc from `start` to `end` with radius `radius` (negative: the larger
/// arc).
pub fn centre_from_radius(
    start: [f64; 2],
    end: [f64; 2],
    radius: f64,
    clockwise: bool,
    tolerance: f64,
) -> Result<[f64; 2], String> {
    let (dx, dy) = (end[0] - start[0], end[1] - start[1]);
    let chord = (dx * dx + dy * dy).sqrt();
    if chord == 0.0 {
        return Err(
            "R-format arc ending where it starts: a full circle needs the centre (I J K)".into(),
        );
    }
    let r = radius.abs();
    let half = chord / 2.0;
    if half - r > tolerance {
        return Err(format!(
            "arc radius {} mm too small to reach the end point ({} mm away)",
            mm(r),
            mm(chord)
        ));
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

/// Checks that `end` lies on the circle about `centre` through `start`, within
/// `tolerance`; a zero radius is an error too.
pub fn check_end(
    start: [f64; 2],
    end: [f64; 2],
    centre: [f64; 2],
    tolerance: f64,
) -> Result<(), String> {
    let r0 = dist(start, centre);
    let r1 = dist(end, centre);
    if r0 == 0.0 {
        return Err("arc with zero radius (its centre is its start point)".into());
    }
    let d = (r1 - r0).abs();
    if d > tolerance {
        return Err(format!(
            "arc end is off its circle: start radius {} mm, end radius {} mm \
             (they differ by {} mm; the tolerance is {} mm)",
            mm(r0),
            mm(r1),
            mm(d),
            mm(tolerance)
        ));
    }
    Ok(())
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
    fn an_end_off_the_circle_is_reported_in_mm() {
        let e = check_end([5e6, 0.0], [0.0, 5.1e6], [0.0, 0.0], 2000.0).unwrap_err();
        assert!(e.contains("start radius 5 mm, end radius 5.1 mm"), "{e}");
    }
}
