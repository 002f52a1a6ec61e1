//! The hexapod-xy's channel map for the contour controller (`crate::kinematics::ContourMap`):
//! the forward kinematics of platform plus table, linearised at a commanded pose, and
//! the inverse's Jacobian, in `f32` from the legs' directions
//! ([`super::hexapod::Hexapod::rows_f32`]).
//!
//! **What it is.** One Newton step of the platform's forward kinematics plus the
//! table, as exact as the measured errors are small (their square relative to the
//! lever, ~1e-6 for 10 µm over 100 mm). Legs to the platform's motion (δp, ω) by the
//! inverse of the rows; then δw = Rᵀ·(δT − δp − ω × (T − p)), δA = −ω_x / cos b,
//! δB = −ω_y (R = Ry(b)·Rx(a), b = −B; the platform's spin about the vertical tool
//! does not turn the tool direction). `to_joint` is the split's derivatives through
//! the rows.
//!
//! **In phases.** [`MapBuilder::step`] does a seventh of the work per call, so that
//! the controller's tick carries a bounded share of it (docs/performance.md): the
//! split; the legs' rows; `to_joint`; the rows' LU factorisation (partial pivoting);
//! `to_pose` of legs 1–2, of legs 3–4, of legs 5–6 and the table. A map is therefore
//! complete every [`MAP_PHASES`] ticks, at the pose of its first phase: up to 14
//! ticks old when the bank stops using it, 0.28 mm at the hexapod-xy's 20 mm/s, which
//! changes the map by about that over the lever (~1e-3 relative) and the contour
//! errors it estimates by as much.

// Matrix arithmetic over index-addressed rows and columns reads best with an index.
#![allow(clippy::needless_range_loop)]

use super::hexapod_xy::{turned_derivatives, HexapodXy};
use super::{Pose, Unreachable};
use crate::config::{Drive, MachineConfig, MAX_JOINTS, MAX_SERVOS};
use crate::kinematics::{ContourMap, POSE_AXES};
use crate::math::{i64_to_f32, ONE_Q31};

/// Calls of [`MapBuilder::step`] per map.
pub const MAP_PHASES: u8 = 7;

/// No servo channel (in [`MapBuilder`]'s joint-to-channel table).
const NO_CHANNEL: u8 = u8::MAX;

// A joint-indexed map of the hexapod-xy's eight joints is a channel-indexed one with
// the identity table.
const _: () = assert!(MAX_SERVOS >= 8);

/// The map under construction, and what its phases hand each other.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapBuilder {
    /// The phase the next [`MapBuilder::step`] runs, 0..[`MAP_PHASES`].
    phase: u8,
    /// Servo channel of each joint ([`NO_CHANNEL`] for none).
    channel: [u8; MAX_JOINTS],
    /// The legs' rows (unit direction, moment) at the pose; then their LU factors
    /// (L below the diagonal, U above it, 1/u_kk on it).
    rows: [[f32; 6]; 6],
    /// Row order of the factorisation.
    perm: [u8; 6],
    /// The platform's rotation R.
    r: [[f32; 3]; 3],
    /// The platform's origin p, mm.
    p: [f32; 3],
    /// Tool tip less the platform origin, T − p, mm.
    d: [f32; 3],
    /// The pose less the platform's home, mm.
    v: [f32; 3],
    /// The table is at an end of its X, Y travel.
    clamped: [bool; 2],
    map: ContourMap,
}

impl MapBuilder {
    /// A builder for `machine`'s servo channels, at its first phase.
    pub fn new(machine: &MachineConfig) -> Self {
        let mut channel = [NO_CHANNEL; MAX_JOINTS];
        for (j, jc) in machine.joints.iter().enumerate().take(MAX_JOINTS) {
            if let Drive::Servo { channel: c } = jc.drive {
                if (c as usize) < MAX_SERVOS {
                    channel[j] = c;
                }
            }
        }
        Self::with_channels(channel)
    }

    fn with_channels(channel: [u8; MAX_JOINTS]) -> Self {
        Self {
            phase: 0,
            channel,
            rows: [[0.0; 6]; 6],
            perm: [0; 6],
            r: [[0.0; 3]; 3],
            p: [0.0; 3],
            d: [0.0; 3],
            v: [0.0; 3],
            clamped: [false; 2],
            map: ContourMap::NONE,
        }
    }

    /// The map as far as it is built: whole right after [`MapBuilder::step`] returned
    /// it.
    pub fn map(&self) -> &ContourMap {
        &self.map
    }

    /// Starts the next map afresh at the next step.
    pub fn restart(&mut self) {
        self.phase = 0;
    }

    /// One phase of the map at `pose` (the pose counts at the first phase only); the
    /// map when this phase completes it. A pose the split refuses, or a singular one,
    /// starts over (the bank keeps the map it has).
    pub fn step(&mut self, k: &HexapodXy, pose: &Pose) -> Option<&ContourMap> {
        let phase = self.phase;
        self.phase += 1;
        match phase {
            0 => {
                if self.split(k, pose).is_err() {
                    self.phase = 0;
                }
            }
            1 => self.rows = k.hexapod.rows_f32(&self.p, &self.r),
            2 => self.joint_rows(),
            3 => {
                if !self.factor() {
                    self.phase = 0;
                }
            }
            4 => self.pose_columns(0..2),
            5 => self.pose_columns(2..4),
            _ => {
                self.pose_columns(4..8);
                self.phase = 0;
                return Some(&self.map);
            }
        }
        None
    }

    /// Phase 0: the split at `pose`: the platform's origin and rotation, the tool
    /// tip's offset from it, the table's clamp (phase 1 forms the legs' rows).
    fn split(&mut self, k: &HexapodXy, pose: &Pose) -> Result<(), Unreachable> {
        let (platform, t, rq) = k.split_rotated(pose)?;
        self.r = rq.map(|row| row.map(|x| x as f32 / ONE_Q31));
        let mm = |v: i64| i64_to_f32(v) * 1e-6;
        let p = [mm(platform[0]), mm(platform[1]), mm(platform[2])];
        self.d = [mm(t[0]) - p[0], mm(t[1]) - p[1], mm(k.tool_z) - p[2]];
        self.p = p;
        self.v = [0, 1, 2].map(|i| mm(pose[i] - k.home[i]));
        self.clamped = k.clamped(&t);
        Ok(())
    }

    /// R's sines and cosines: R = Ry(b)·Rx(a) holds cos b, sin a, cos a, −sin b.
    fn trig(&self) -> (f32, f32, f32, f32) {
        let r = &self.r;
        (-r[1][2], r[1][1], -r[2][0], r[0][0])
    }

    /// Phase 2: `to_joint`, the split's derivatives per mm and degree through the rows.
    fn joint_rows(&mut self) {
        let (sa, ca, sb, cb) = self.trig();
        let rad = core::f32::consts::PI / 180.0;
        let drv = turned_derivatives(sa, ca, sb, cb, self.v, rad);
        // (δp, ω) per unit of each pose axis: δp_xy = −∂(R·v)_xy only where the table
        // is clamped, δp_z = −∂(R·v)_z; ω = −(cos b, 0, −sin b)·δA − ŷ·δB, radians.
        let zero = [0.0f32; POSE_AXES];
        let dp = [0, 1].map(|i| {
            if self.clamped[i] {
                drv[i].map(|x| -x)
            } else {
                zero
            }
        });
        let dz = drv[2].map(|x| -x);
        let (wa_x, wa_z, wb_y) = (-cb * rad, sb * rad, -rad);
        for j in 0..6 {
            let leg = self.rows[j];
            let mut row = [0.0f32; POSE_AXES];
            for a in 0..POSE_AXES {
                row[a] = leg[0] * dp[0][a] + leg[1] * dp[1][a] + leg[2] * dz[a];
            }
            row[3] += leg[3] * wa_x + leg[5] * wa_z;
            row[4] += leg[4] * wb_y;
            self.put_joint(j, row);
        }
        for i in 0..2 {
            let row = if self.clamped[i] { zero } else { drv[i] };
            self.put_joint(6 + i, row);
        }
    }

    fn put_joint(&mut self, j: usize, row: [f32; POSE_AXES]) {
        let c = self.channel[j] as usize;
        if c < MAX_SERVOS {
            self.map.to_joint[c] = row;
        }
    }

    /// Phase 3: the rows' LU factorisation with partial pivoting, in place; false when a
    /// pivot is below 1e-6 of the largest entry (singular).
    fn factor(&mut self) -> bool {
        let a = &mut self.rows;
        // A compare, not `f32::max` (a call to `fmaxf` on the M4); entries are finite.
        let scale = a.iter().flatten().fold(0.0f32, |s, v| {
            let m = v.abs();
            if m > s {
                m
            } else {
                s
            }
        });
        self.perm = [0, 1, 2, 3, 4, 5];
        for c in 0..6 {
            let mut p = c;
            for r in c + 1..6 {
                if a[r][c].abs() > a[p][c].abs() {
                    p = r;
                }
            }
            if a[p][c].abs().partial_cmp(&(1e-6 * scale)) != Some(core::cmp::Ordering::Greater) {
                return false;
            }
            a.swap(c, p);
            self.perm.swap(c, p);
            let inv = 1.0 / a[c][c];
            a[c][c] = inv;
            for r in c + 1..6 {
                let f = a[r][c] * inv;
                a[r][c] = f;
                for j in c + 1..6 {
                    a[r][j] -= f * a[c][j];
                }
            }
        }
        true
    }

    /// Column `j` of the rows' inverse: the platform's motion (δp, ω) per unit change
    /// of leg `j`, by forward and back substitution.
    fn solve(&self, j: usize) -> [f32; 6] {
        let a = &self.rows;
        let mut x = [0.0f32; 6];
        for i in 0..6 {
            let mut s = if self.perm[i] as usize == j { 1.0 } else { 0.0 };
            for m in 0..i {
                s -= a[i][m] * x[m];
            }
            x[i] = s;
        }
        for i in (0..6).rev() {
            let mut s = x[i];
            for m in i + 1..6 {
                s -= a[i][m] * x[m];
            }
            x[i] = s * a[i][i];
        }
        x
    }

    /// Phases 4 to 6: `to_pose` of joints `joints` (legs by their inverse column, the
    /// table's axes directly).
    fn pose_columns(&mut self, joints: core::ops::Range<usize>) {
        let (_, _, _, cb) = self.trig();
        let deg = 180.0 / core::f32::consts::PI;
        for j in joints {
            let (dp, w, dt) = if j < 6 {
                let x = self.solve(j);
                ([x[0], x[1], x[2]], [x[3], x[4], x[5]], [0.0; 3])
            } else {
                let mut dt = [0.0; 3];
                dt[j - 6] = 1.0;
                ([0.0; 3], [0.0; 3], dt)
            };
            let d = &self.d;
            let wxd = [
                w[1] * d[2] - w[2] * d[1],
                w[2] * d[0] - w[0] * d[2],
                w[0] * d[1] - w[1] * d[0],
            ];
            let m = [0, 1, 2].map(|i| dt[i] - dp[i] - wxd[i]);
            let c = self.channel[j] as usize;
            if c >= MAX_SERVOS {
                continue;
            }
            let r = &self.r;
            for i in 0..3 {
                self.map.to_pose[i][c] = r[0][i] * m[0] + r[1][i] * m[1] + r[2][i] * m[2];
            }
            self.map.to_pose[3][c] = -w[0] / cb * deg;
            self.map.to_pose[4][c] = -w[1] * deg;
        }
    }
}

impl HexapodXy {
    /// The joints' map to the pose at `pose`, joint-indexed (joint j in column or row
    /// j, q1..q8 as channels 0..7), all phases at once: what [`MapBuilder`] builds over [`MAP_PHASES`] ticks.
    pub fn contour_map(&self, pose: &Pose) -> Result<ContourMap, Unreachable> {
        let identity = core::array::from_fn(|j| if j < 8 { j as u8 } else { NO_CHANNEL });
        let mut b = MapBuilder::with_channels(identity);
        b.split(self, pose)?;
        b.phase = 1;
        for _ in 1..MAP_PHASES {
            if let Some(map) = b.step(self, pose) {
                return Ok(*map);
            }
            if b.phase == 0 {
                break;
            }
        }
        Err(Unreachable::Singular)
    }
}

#[cfg(test)]
mod tests {
    use super::super::hexapod_xy::tests::{machine, DEG, MM};
    use super::*;

    #[test]
    fn the_phases_build_the_whole_map_at_the_pose_of_the_first() {
        let (m, k) = machine();
        let mut b = MapBuilder::new(&m);
        let first = [8 * MM, -6 * MM, 282 * MM, 9 * DEG, -7 * DEG, 0];
        let later = [9 * MM, -5 * MM, 283 * MM, 8 * DEG, -6 * DEG, 0];
        let want = ContourMap::of_joints(&m, &k.contour_map(&first).unwrap());
        assert_ne!(
            want,
            ContourMap::of_joints(&m, &k.contour_map(&later).unwrap())
        );
        for round in 0..3 {
            for phase in 0..MAP_PHASES {
                let pose = if phase == 0 { first } else { later };
                let got = b.step(&k, &pose).copied();
                if phase + 1 < MAP_PHASES {
                    assert_eq!(got, None, "round {round}, phase {phase}");
                } else {
                    assert_eq!(got, Some(want), "round {round}");
                }
            }
        }
    }

    #[test]
    fn a_pose_the_split_refuses_starts_the_map_over() {
        let (m, k) = machine();
        let mut b = MapBuilder::new(&m);
        let pose = [0, 0, 275 * MM, 0, 0, 0];
        b.step(&k, &pose);
        b.step(&k, &pose);
        let far = [0, 0, 2_000 * MM, 0, 0, 0];
        b.restart();
        assert_eq!(b.step(&k, &far), None);
        assert_eq!(b.phase, 0, "refused at the first phase: starts over");
        let want = ContourMap::of_joints(&m, &k.contour_map(&pose).unwrap());
        let got = (0..MAP_PHASES)
            .filter_map(|_| b.step(&k, &pose).copied())
            .last();
        assert_eq!(got, Some(want));
    }

    /// docs/contour.md §6 weighs the held-axis direction error against this: one
    /// encoder count (1 µm) of one leg turns the tool axis by 0.04–0.18 mdeg at home.
    #[test]
    fn one_micrometre_of_a_leg_turns_the_tool_axis_by_0_04_to_0_18_millidegrees_at_home() {
        let (m, k) = machine();
        let map = k.contour_map(&m.home).unwrap();
        for leg in 0..6 {
            // degrees per mm of the leg are millidegrees per µm.
            let mdeg = [3, 4].map(|a| map.to_pose[a][leg].abs());
            assert!(
                mdeg.iter().all(|t| (0.04..=0.18).contains(t)),
                "leg {}: A, B {mdeg:?} mdeg per µm",
                leg + 1
            );
        }
    }
}
