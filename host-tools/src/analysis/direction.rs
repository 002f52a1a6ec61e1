//! The tool's direction from a pose's A and B, and the angle between two directions:
//! for the tool-direction errors of five-axis machines (`contour_study`, and
//! `calibrate::true_path`).

/// The tool axis for A, B (degrees): Rx(A)·Ry(B)·ẑ.
pub fn tool_axis(a_deg: f64, b_deg: f64) -> [f64; 3] {
    let (sa, ca) = a_deg.to_radians().sin_cos();
    let (sb, cb) = b_deg.to_radians().sin_cos();
    [sb, -sa * cb, ca * cb]
}

/// Angle between two unit vectors, degrees (from the cross and dot products, exact
/// for small angles).
pub fn angle_deg(u: [f64; 3], v: [f64; 3]) -> f64 {
    let c = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    let s = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    s.atan2(u[0] * v[0] + u[1] * v[1] + u[2] * v[2])
        .to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_angle_of_two_tool_axes_is_the_tilt_between_them() {
        let a = angle_deg(tool_axis(0.0, 0.0), tool_axis(0.0, 1e-6));
        assert!((a - 1e-6).abs() < 1e-15, "{a}");
        let a = angle_deg(tool_axis(10.0, 0.0), tool_axis(10.0 + 3e-6, 0.0));
        assert!((a - 3e-6).abs() < 1e-14, "{a}");
    }
}
