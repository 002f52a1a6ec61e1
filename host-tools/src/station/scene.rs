//! The mechanism as the page draws it, from the machine file's geometry and the
//! controller's commanded pose and joints: segments and polygons in the machine frame
//! (mm, Z up), and the transform that puts the workpiece (the tool path) on the table.
//! The page draws whatever it is sent; the geometry is known here, once.

use pkmc::config::{KinematicsConfig, MachineConfig, AXES, AXIS_NAMES};
use serde_json::{json, Value};

type P3 = [f64; 3];

fn mm(v: i64) -> f64 {
    v as f64 / 1e6
}

fn add(a: P3, b: P3) -> P3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn sub(a: P3, b: P3) -> P3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// 3 × 3 rotation as rows.
type M3 = [[f64; 3]; 3];

fn mul(m: &M3, v: P3) -> P3 {
    std::array::from_fn(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

fn rot_x(deg: f64) -> M3 {
    let (s, c) = deg.to_radians().sin_cos();
    [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
}

fn rot_y(deg: f64) -> M3 {
    let (s, c) = deg.to_radians().sin_cos();
    [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
}

fn rot_z(deg: f64) -> M3 {
    let (s, c) = deg.to_radians().sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

fn mat_mul(a: &M3, b: &M3) -> M3 {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

/// Segments and polygons of one drawing.
#[derive(Default)]
struct Drawing {
    segs: Vec<Value>,
    polys: Vec<Value>,
    /// Workpiece to machine frame: rotation rows and translation.
    work: (M3, P3),
}

impl Drawing {
    fn seg(&mut self, a: P3, b: P3, kind: &str) {
        let r = super::program::round3;
        self.segs.push(json!([
            r(a[0]),
            r(a[1]),
            r(a[2]),
            r(b[0]),
            r(b[1]),
            r(b[2]),
            kind
        ]));
    }

    fn poly(&mut self, pts: &[P3], kind: &str) {
        let r = super::program::round3;
        let pts: Vec<Value> = pts.iter().map(|p| json!(p.map(r))).collect();
        self.polys.push(json!([kind, pts]));
    }
}

/// The machine as the `hello` message describes it: kind, axes, joints and a box that
/// holds the mechanism.
pub fn describe(machine: &MachineConfig, joint_names: &[String]) -> Value {
    let kind = match machine.kinematics {
        KinematicsConfig::Cartesian { .. } => "cartesian",
        KinematicsConfig::H4Table(_) => "h4",
        KinematicsConfig::Hexapod(_) => "hexapod",
        KinematicsConfig::HexapodXy(_) => "hexapod-xy",
    };
    let axes: Vec<String> = (0..AXES)
        .filter(|&i| machine.axes[i].max_velocity > 0)
        .map(|i| AXIS_NAMES[i].to_string())
        .collect();
    // The joints at the machine's home pose: where the range bars say "home".
    let kin = pkmc::kinematics::MachineKinematics::new(machine);
    let mut q = [0i64; pkmc::config::MAX_JOINTS];
    let at_home = kin
        .inverse_checked(&machine.home, &machine.joints, &mut q)
        .is_ok();
    let joints: Vec<Value> = machine
        .joints
        .iter()
        .enumerate()
        .map(|(j, jc)| {
            let unit = if jc.rotary { "deg" } else { "mm" };
            json!({
                "name": joint_names.get(j).cloned().unwrap_or_else(|| format!("J{}", j + 1)),
                "unit": unit,
                "min": pkmc::units::to_user(jc.min, jc.rotary),
                "max": pkmc::units::to_user(jc.max, jc.rotary),
                "home": at_home.then(|| pkmc::units::to_user(q[j], jc.rotary)),
                "servo": matches!(jc.drive, pkmc::config::Drive::Servo { .. }),
            })
        })
        .collect();
    let (lo, hi) = bounds(machine);
    json!({
        "name": machine.name.as_str(),
        "kind": kind,
        "axes": axes,
        "joints": joints,
        "bounds": {"min": lo, "max": hi},
    })
}

/// Joint names for a machine without a machine file's names: the H-4's carriages and
/// table, the hexapod's arms (the thesis' Arm1…), a Cartesian machine's axes.
pub fn default_joint_names(machine: &MachineConfig) -> Vec<String> {
    let n = machine.joints.len();
    match machine.kinematics {
        KinematicsConfig::Cartesian { axis_of_joint } => (0..n)
            .map(|j| AXIS_NAMES[axis_of_joint[j] as usize].to_string())
            .collect(),
        KinematicsConfig::H4Table(_) => (0..n)
            .map(|j| match j {
                4 => "A".to_string(),
                j => format!("q{}", j + 1),
            })
            .collect(),
        KinematicsConfig::Hexapod(_) => (0..n).map(|j| format!("Arm{}", j + 1)).collect(),
        KinematicsConfig::HexapodXy(_) => (0..n)
            .map(|j| match j {
                6 => "TableX".to_string(),
                7 => "TableY".to_string(),
                j => format!("Leg{}", j + 1),
            })
            .collect(),
    }
}

/// Travel of joint `j`, mm or degrees.
fn travel(machine: &MachineConfig, j: usize) -> (f64, f64) {
    let jc = &machine.joints[j];
    (
        pkmc::units::to_user(jc.min, jc.rotary),
        pkmc::units::to_user(jc.max, jc.rotary),
    )
}

fn bounds(machine: &MachineConfig) -> (P3, P3) {
    match machine.kinematics {
        KinematicsConfig::H4Table(g) => {
            let r = g
                .rails
                .iter()
                .flat_map(|p| [mm(p[0]).abs(), mm(p[1]).abs()])
                .fold(0.0, f64::max);
            let top = (0..4).map(|j| travel(machine, j).1).fold(0.0, f64::max);
            let low = mm(g.table_pivot[2]) - 100.0;
            (
                [-r - 50.0, -r - 50.0, low],
                [r + 50.0, r + 50.0, top + 50.0],
            )
        }
        KinematicsConfig::Hexapod(g)
        | KinematicsConfig::HexapodXy(pkmc::config::HexapodXyGeometry { hexapod: g, .. }) => {
            let r = g
                .base
                .iter()
                .map(|p| mm(p[0]).hypot(mm(p[1])))
                .fold(0.0, f64::max);
            let top = mm(machine.home[2]) + 150.0;
            let r = r.max(
                (6..machine.joints.len())
                    .map(|j| travel(machine, j).1.abs())
                    .fold(0.0, f64::max),
            );
            ([-r - 50.0, -r - 50.0, 0.0], [r + 50.0, r + 50.0, top])
        }
        KinematicsConfig::Cartesian { .. } => {
            let (lo, hi) = cartesian_box(machine);
            (lo.map(|v| v - 20.0), hi.map(|v| v + 20.0))
        }
    }
}

/// The travel of a Cartesian machine's X Y Z joints (±100 mm for an axis it lacks).
fn cartesian_box(machine: &MachineConfig) -> (P3, P3) {
    let mut lo = [-100.0; 3];
    let mut hi = [100.0; 3];
    if let KinematicsConfig::Cartesian { axis_of_joint } = machine.kinematics {
        for (j, &a) in axis_of_joint.iter().enumerate().take(machine.joints.len()) {
            let a = a as usize;
            if a < 3 {
                (lo[a], hi[a]) = travel(machine, j);
            }
        }
    }
    (lo, hi)
}

/// The `scene` of a status: the mechanism at `pose` (mm, degrees, workpiece) with
/// commanded `joints` (mm or degrees).
pub fn scene(machine: &MachineConfig, pose: &[f64; AXES], joints: &[f64]) -> Value {
    let mut d = Drawing {
        work: (
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0; 3],
        ),
        ..Drawing::default()
    };
    match machine.kinematics {
        KinematicsConfig::H4Table(g) => h4(&mut d, machine, &g, pose, joints),
        KinematicsConfig::Hexapod(g) => hexapod(&mut d, &g, pose),
        KinematicsConfig::HexapodXy(g) => hexapod_xy(&mut d, machine, &g, pose, joints),
        KinematicsConfig::Cartesian { .. } => cartesian(&mut d, machine, pose),
    }
    let (m, t) = d.work;
    let work: Vec<f64> = (0..3)
        .flat_map(|i| [m[i][0], m[i][1], m[i][2], t[i]])
        .map(|v| (v * 1e6).round() / 1e6)
        .collect();
    json!({"segs": d.segs, "polys": d.polys, "work": work})
}

fn h4(
    d: &mut Drawing,
    machine: &MachineConfig,
    g: &pkmc::config::H4TableGeometry,
    pose: &[f64; AXES],
    joints: &[f64],
) {
    let pivot = g.table_pivot.map(mm);
    let tilt = rot_x(pose[3]);
    // Workpiece point p sits at pivot + Rx(A)(p - pivot).
    d.work = (tilt, sub(pivot, mul(&tilt, pivot)));
    let on_table = |p: P3| add(pivot, mul(&tilt, sub(p, pivot)));
    let tip = on_table([pose[0], pose[1], pose[2]]);
    let e = add(tip, [0.0, 0.0, mm(g.tool_length)]);
    let (s, c) = pose[5].to_radians().sin_cos();
    let half = mm(g.bar_half);
    d.seg(e, tip, "tool");
    d.seg(
        add(e, [-half * c, -half * s, 0.0]),
        add(e, [half * c, half * s, 0.0]),
        "bar",
    );
    let mut tops = Vec::new();
    let mut plate = Vec::new();
    for i in 0..4 {
        let (lo, hi) = travel(machine, i);
        let rail = g.rails[i].map(mm);
        d.seg(
            [rail[0], rail[1], lo - 20.0],
            [rail[0], rail[1], hi + 20.0],
            "rail",
        );
        tops.push([rail[0], rail[1], hi + 20.0]);
        let q = joints.get(i).copied().unwrap_or(lo);
        let carriage = [rail[0], rail[1], q];
        d.seg(
            add(carriage, [0.0, 0.0, -15.0]),
            add(carriage, [0.0, 0.0, 15.0]),
            "carriage",
        );
        let side = g.sides[i] as f64 * half;
        let at = add(add(e, [side * c, side * s, 0.0]), g.attach[i].map(mm));
        d.seg(at, carriage, "forearm");
        plate.push(at);
        d.seg(add(e, [side * c, side * s, 0.0]), at, "bar");
    }
    // The travelling plate: the four forearm joints, in turn around their middle.
    let mid = plate
        .iter()
        .fold([0.0; 3], |m, p| add(m, p.map(|v| v / 4.0)));
    plate.sort_by(|a, b| {
        let angle = |p: &P3| (p[1] - mid[1]).atan2(p[0] - mid[0]);
        angle(a).total_cmp(&angle(b))
    });
    d.poly(&plate, "platform");
    for i in 0..4 {
        d.seg(tops[i], tops[(i + 1) % 4], "frame");
    }
    // The table: a plate in the workpiece's plane through the pivot, and its axis.
    let z = pivot[2];
    let corners: Vec<P3> = [
        [-200.0, -160.0],
        [200.0, -160.0],
        [200.0, 160.0],
        [-200.0, 160.0],
    ]
    .iter()
    .map(|p| on_table([p[0], p[1], z]))
    .collect();
    d.poly(&corners, "table");
    d.seg(
        [pivot[0] - 240.0, pivot[1], z],
        [pivot[0] + 240.0, pivot[1], z],
        "axis",
    );
}

fn hexapod(d: &mut Drawing, g: &pkmc::config::HexapodGeometry, pose: &[f64; AXES]) {
    let r = mat_mul(&mat_mul(&rot_z(pose[5]), &rot_y(pose[4])), &rot_x(pose[3]));
    let origin = [pose[0], pose[1], pose[2]];
    let base: Vec<P3> = g.base.iter().map(|p| p.map(mm)).collect();
    let plat: Vec<P3> = g
        .platform
        .iter()
        .map(|b| add(origin, mul(&r, b.map(mm))))
        .collect();
    d.poly(&base, "base");
    d.poly(&plat, "platform");
    for i in 0..6 {
        d.seg(base[i], plat[i], "leg");
    }
    // The platform's own axes, 60 mm, at its origin.
    let len = 60.0;
    d.seg(origin, add(origin, mul(&r, [len, 0.0, 0.0])), "axis");
    d.seg(origin, add(origin, mul(&r, [0.0, len, 0.0])), "axis");
    d.seg(origin, add(origin, mul(&r, [0.0, 0.0, len])), "tool");
}

/// The hexapod at the platform pose the split gives, the workpiece on it, and the
/// tool on the X-Y table above.
fn hexapod_xy(
    d: &mut Drawing,
    machine: &MachineConfig,
    g: &pkmc::config::HexapodXyGeometry,
    pose: &[f64; AXES],
    joints: &[f64],
) {
    let units = pose.map(|v| (v * 1e6).round() as i64);
    let kin = pkmc::kinematics::MachineKinematics::new(machine);
    let pkmc::kinematics::MachineKinematics::HexapodXy(k) = kin else {
        return;
    };
    let Ok((platform, _)) = k.split(&units) else {
        return;
    };
    let platform = platform.map(|v| v as f64 / 1e6);
    hexapod(d, &g.hexapod, &platform);
    // Workpiece point w sits at p + R·(w − home).
    let r = mat_mul(&rot_y(platform[4]), &rot_x(platform[3]));
    let home = g.platform_home.map(mm);
    d.work = (
        r,
        sub([platform[0], platform[1], platform[2]], mul(&r, home)),
    );
    let tz = mm(g.tool_z);
    let t = [
        joints.get(6).copied().unwrap_or(0.0),
        joints.get(7).copied().unwrap_or(0.0),
    ];
    let tip = [t[0], t[1], tz];
    d.seg(tip, add(tip, [0.0, 0.0, 60.0]), "tool");
    // The table's travel (a frame over the platform) and its carriage.
    let (x, y) = (travel(machine, 6), travel(machine, 7));
    let top = tz + 60.0;
    d.poly(
        &[
            [x.0, y.0, top],
            [x.1, y.0, top],
            [x.1, y.1, top],
            [x.0, y.1, top],
        ],
        "table",
    );
    d.seg([x.0, t[1], top], [x.1, t[1], top], "rail");
    d.seg([t[0], y.0, top], [t[0], y.1, top], "carriage");
}

fn cartesian(d: &mut Drawing, machine: &MachineConfig, pose: &[f64; AXES]) {
    let (lo, hi) = cartesian_box(machine);
    let p = [pose[0], pose[1], pose[2]];
    // The frame: the travel box.
    let corner = |i: usize| -> P3 {
        [
            if i & 1 == 0 { lo[0] } else { hi[0] },
            if i & 2 == 0 { lo[1] } else { hi[1] },
            if i & 4 == 0 { lo[2] } else { hi[2] },
        ]
    };
    for i in 0..8 {
        for bit in [1, 2, 4] {
            if i & bit == 0 {
                d.seg(corner(i), corner(i | bit), "frame");
            }
        }
    }
    // The axes: the gantry's X beam, the Y rails' carriage, the Z column.
    d.seg([lo[0], p[1], hi[2]], [hi[0], p[1], hi[2]], "rail");
    d.seg([p[0], lo[1], hi[2]], [p[0], hi[1], hi[2]], "axis");
    d.seg([p[0], p[1], hi[2]], [p[0], p[1], p[2] + 30.0], "carriage");
    d.seg([p[0], p[1], p[2] + 30.0], p, "tool");
    d.poly(
        &[
            [lo[0], lo[1], lo[2]],
            [hi[0], lo[1], lo[2]],
            [hi[0], hi[1], lo[2]],
            [lo[0], hi[1], lo[2]],
        ],
        "table",
    );
}
