//! The whole programs that `record` runs through `nc-send`'s link client: G-code
//! generated here, and report B's helices read from `examples/` at compile time.

use pkmc::drive::recorder::{Setup, Signal, Trigger, MAX_SIGNALS};

/// One recorded program.
pub struct Program {
    /// Short name (`h4_seg0.05mm`, …).
    pub name: String,
    /// Machine: 0 the H-4 with rolling table, 1 the hexapod, 2 the hexapod-xy
    /// ([`crate::machine`]).
    pub machine: u32,
    /// The G-code.
    pub text: String,
    /// Operator events during the run (hold, resume, feed override changes), and an
    /// e-stop: the calls where the controller re-profiles and raises its alarm.
    pub events: bool,
    /// Motion ticks before the programmed path starts (its first rapid, where that is
    /// long), by which the operator of an `events` program delays every event.
    pub lead_ticks: u64,
    /// A ball (centre, radius plus the probe tip's, mm) the simulator's touch probe
    /// touches: the program probes it (G38.2), and runs a stage at a time as
    /// `nc-send` runs such a program.
    pub probe: Option<([f64; 3], f64)>,
    /// The data recorder armed before the job ([`record_tick`], [`record_servo`]).
    pub record: Option<Setup>,
    /// The servo bench whose tick stands for the program's servo periods in its 1 ms
    /// figure (`.ci/m4count.py`); `None`: the servo interrupt of the machine's bank.
    pub servo_bench: Option<&'static str>,
}

/// 8 signals every tick, streamed (`Trigger::Stream`), on a servo machine: joint 0's
/// commanded and measured position, following error and DAC code, the path speed, the
/// contour errors of the path and of the tool's direction, the NC line: every kind
/// of signal the tick forms.
pub fn record_tick() -> Setup {
    use Signal::*;
    setup(
        [
            Commanded(0),
            Measured(0),
            FollowingError(0),
            Output(0),
            PathSpeed,
            ContourError,
            DirectionError,
            Line,
        ],
        false,
    )
}

/// 8 signals every servo period on the hexapod-xy, a capture waiting for an alarm
/// (none comes: the ring is written every period all the job long, the worst case of
/// a capture; a stream of these 300 kB/s would lose samples, one piece a tick being
/// its limit): leg 0's commanded and measured position, following error and DAC
/// code, the table X's (joint 6) following error and DAC code, the contour errors of
/// the path and of the tool's direction, all staged by the servo side
/// (`crate::pacer::HEXAPOD_XY_SIGNALS`).
pub fn record_servo() -> Setup {
    use Signal::*;
    Setup {
        trigger: Trigger::Alarm,
        ..setup(
            [
                Commanded(0),
                Measured(0),
                FollowingError(0),
                Output(0),
                FollowingError(6),
                Output(6),
                ContourError,
                DirectionError,
            ],
            true,
        )
    }
}

/// A continuous capture of `signals`, every servo period or every tick, undecimated.
fn setup(signals: [Signal; MAX_SIGNALS], servo: bool) -> Setup {
    Setup {
        signals: signals.map(Signal::id),
        count: MAX_SIGNALS as u8,
        servo,
        decimate: 1,
        trigger: Trigger::Stream,
        pre: 0,
    }
}

/// Touches of a ball at `centre` of radius `r` (mm) from five directions: a rapid to
/// 4 mm outside, G38.2 at 300 mm/min to 3 mm inside (it stops on the surface), back.
fn touches(centre: [f64; 3], r: f64) -> String {
    let mut t = String::from("G21 G90\n");
    let dirs: [[f64; 3]; 5] = [
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 1.0],
        [0.0, -1.0, 1.0],
        [-1.0, 1.0, 2.0],
        [1.0, 1.0, 0.3],
    ];
    for u in dirs {
        let n = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
        let at = |d: f64| -> Vec<String> { (0..3).map(|i| f(centre[i] + u[i] / n * d)).collect() };
        let (s, e) = (at(r + 4.0), at(r - 3.0));
        t += &format!("G0 X{} Y{} Z{}\n", s[0], s[1], s[2]);
        t += &format!("G38.2 X{} Y{} Z{} F300\n", e[0], e[1], e[2]);
        t += &format!("G0 X{} Y{} Z{}\n", s[0], s[1], s[2]);
    }
    t + "M2\n"
}

/// Formats mm or degrees for G-code (0.1 µm, 0.1 µ°).
fn f(v: f64) -> String {
    let s = format!("{v:.4}");
    if s == "-0.0000" {
        "0.0000".into()
    } else {
        s
    }
}

/// A sine along X, `amp` mm high, `wave` mm long, from `x0` over `len` mm of X at
/// height `z`, in G1 segments of `seg` mm of path each (the last one shorter), at F6000.
fn sine(seg: f64, len: f64, x0: f64, z: f64, amp: f64, wave: f64) -> String {
    sine_at(6000, seg, len, x0, z, amp, wave)
}

/// [`sine`] at feed `feed` mm/min.
fn sine_at(feed: u32, seg: f64, len: f64, x0: f64, z: f64, amp: f64, wave: f64) -> String {
    sine_blend(feed, "G64", seg, len, x0, z, amp, wave)
}

/// [`sine_at`] in path mode `mode` (`G64 P0.01` lets `nc-send` merge the segments into
/// curves).
#[allow(clippy::too_many_arguments)]
fn sine_blend(
    feed: u32,
    mode: &str,
    seg: f64,
    len: f64,
    x0: f64,
    z: f64,
    amp: f64,
    wave: f64,
) -> String {
    let k = std::f64::consts::TAU / wave;
    let y = |x: f64| amp * (k * (x - x0)).sin();
    let mut g = format!("G21 G90 {mode}\nG0 X{} Y0 Z{}\nF{feed}\n", f(x0), f(z));
    let mut x = x0;
    while x < x0 + len {
        // The step in X whose chord is `seg` long, to first order.
        let slope = amp * k * (k * (x - x0)).cos();
        x = (x + seg / (1.0 + slope * slope).sqrt()).min(x0 + len);
        g += &format!("G1 X{} Y{}\n", f(x), f(y(x)));
    }
    g + "M2\n"
}

/// The same sine as [`sine`] (0.05 mm segments are not needed: these are the
/// curves themselves) as a chain of `G5` cubics, one per `step` mm of X, each
/// leaving along the sine's tangent, alternating with `G5.1` parabolas (one per
/// `step` mm: the control point where the two end tangents meet) over the second half.
fn g5_sine(step: f64, len: f64, x0: f64, z: f64, amp: f64, wave: f64) -> String {
    let k = std::f64::consts::TAU / wave;
    let y = |x: f64| amp * (k * (x - x0)).sin();
    let dy = |x: f64| amp * k * (k * (x - x0)).cos();
    let mut g = format!("G21 G90 G64 G17\nG0 X{} Y0 Z{}\nF6000\n", f(x0), f(z));
    let n = (len / step).round() as usize;
    for i in 0..n {
        let (a, b) = (x0 + i as f64 * step, x0 + (i + 1) as f64 * step);
        let h = step / 3.0;
        if i < n / 2 {
            // Control points a third of the step along each end's tangent.
            g += &format!(
                "G5 X{} Y{} I{} J{} P{} Q{}\n",
                f(b),
                f(y(b)),
                f(h),
                f(h * dy(a)),
                f(-h),
                f(-h * dy(b))
            );
        } else {
            // Where the tangents at a and b meet (their slopes differ; parallel ones
            // give the midpoint).
            let (sa, sb) = (dy(a), dy(b));
            let xm = if (sa - sb).abs() > 1e-9 {
                (y(b) - y(a) + sa * a - sb * b) / (sa - sb)
            } else {
                (a + b) / 2.0
            };
            let xm = xm.clamp(a, b);
            g += &format!(
                "G5.1 X{} Y{} I{} J{}\n",
                f(b),
                f(y(b)),
                f(xm - a),
                f(sa * (xm - a))
            );
        }
    }
    g + "M2\n"
}

/// A chain of `n` tangent arcs of radius `r` mm, each turning `sweep` degrees,
/// alternately counter-clockwise (G3) and clockwise (G2), starting at (`x0`, 0, `z`)
/// heading along +X, at F6000.
fn arcs(n: usize, r: f64, sweep: f64, x0: f64, z: f64) -> String {
    let mut g = format!("G21 G90 G64 G17\nG0 X{} Y0 Z{}\nF6000\n", f(x0), f(z));
    let (mut p, mut heading) = ([x0, 0.0], 0.0f64);
    let phi = sweep.to_radians();
    for i in 0..n {
        let ccw = i % 2 == 0;
        let side = if ccw { 1.0 } else { -1.0 };
        // The centre lies on the side the arc turns to; the end is the start turned
        // about it.
        let c = [
            p[0] - side * r * heading.sin(),
            p[1] + side * r * heading.cos(),
        ];
        let turn = side * phi;
        let (s, co) = turn.sin_cos();
        let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
        let end = [c[0] + co * dx - s * dy, c[1] + s * dx + co * dy];
        g += &format!(
            "{} X{} Y{} I{} J{}\n",
            if ccw { "G3" } else { "G2" },
            f(end[0]),
            f(end[1]),
            f(c[0] - p[0]),
            f(c[1] - p[1])
        );
        p = end;
        heading += turn;
    }
    g + "M2\n"
}

/// A circle of radius `r` mm about (0, 0) at height `z` in `n` G1 segments at F3000,
/// the rotary axes following `angles(t)` (t from 0 to 1 over the circle: words such as
/// `A12.5 C-3`).
fn five_axis(n: usize, r: f64, z: f64, angles: impl Fn(f64) -> String) -> String {
    let mut g = format!(
        "G21 G90 G64\nG0 X{} Y0 Z{} {}\nF3000\n",
        f(r),
        f(z),
        angles(0.0)
    );
    for i in 1..=n {
        let t = i as f64 / n as f64;
        let a = std::f64::consts::TAU * t;
        g += &format!("G1 X{} Y{} {}\n", f(r * a.cos()), f(r * a.sin()), angles(t));
    }
    g + "M2\n"
}

/// The measured programs, whole, on every machine ([`crate::MACHINES`]).
///
/// On the H-4 and the hexapod: 0.05 mm, 1 mm and 2 mm G1 segments along a sine (and
/// 0.01 mm at F3000 over 20 mm of X) (5 mm high, 40 mm long waves: 8 mm radius at the
/// crests, which both machines take at or near F6000) at F6000, a chain of tangent
/// G2/G3 arcs at F6000, and a five-axis circle with the table turning (H-4: A tilts the
/// table 0–30° and back while C swings ±15°; hexapod: A and B tilt the platform ±8°,
/// C swings ±5°). X spans ±`SINE_MM`/2 about the machine's home (H-4: the tool tip at
/// Z −80 mm, the workpiece frame; hexapod: the platform at Z 450 mm).
///
/// On the hexapod-xy (workpiece coordinates, home X0 Y0 Z275; every axis limited to
/// 20 mm/s, so F6000 runs at 1 200 mm/min): the 0.05 mm sine and its `events` run at
/// Z 275 mm over X ±45 mm ([`HEXAPOD_XY_SINE_MM`], inside the table's ±50 mm travel),
/// their events delayed by the first rapid's 2.35 s, and report B's helices as the examples give them (`examples/helix-b.ngc`,
/// orientation held, and `helix-b-tilt.ngc`, the tool axis tilting with A and B: 500
/// G1 pieces each in G93 inverse-time feed, 10 s of motion).
pub fn programs() -> Vec<Program> {
    let mut out = Vec::new();
    for (m, tag, z) in [(0u32, "h4", -80.0), (1, "hexapod", 450.0)] {
        let x0 = -SINE_MM / 2.0;
        let mut add = |what: &str, text: String| {
            out.push(Program {
                name: format!("{tag}_{what}"),
                machine: m,
                text,
                events: what.ends_with("events"),
                lead_ticks: 0,
                probe: None,
                record: None,
                servo_bench: None,
            })
        };
        add("seg0.05mm", sine(0.05, SINE_MM, x0, z, 5.0, 40.0));
        // Five blocks a tick: the densest case of the end-to-end test, over a fifth of
        // the length (2 300 blocks, as many as the 0.05 mm program).
        add(
            "seg0.01mm_F3000",
            sine_at(3000, 0.01, SINE_MM / 5.0, x0, z, 5.0, 40.0),
        );
        add("events", sine(0.05, SINE_MM, x0, z, 5.0, 40.0));
        add("seg1mm", sine(1.0, SINE_MM, x0, z, 5.0, 40.0));
        add("seg2mm", sine(2.0, SINE_MM, x0, z, 5.0, 40.0));
        // The same sine in G64 P0.01: `nc-send` streams it as curves; and a chain of
        // G5 cubics and G5.1 parabolas.
        add(
            "curves0.05mm",
            sine_blend(6000, "G64 P0.01", 0.05, SINE_MM, x0, z, 5.0, 40.0),
        );
        add("g5", g5_sine(2.0, SINE_MM, x0, z, 5.0, 40.0));
        add(
            "curves_events",
            sine_blend(6000, "G64 P0.01", 0.05, SINE_MM, x0, z, 5.0, 40.0),
        );
        add("arcs", arcs(ARCS, 5.0, 20.0, x0, z));
        let angles: Box<dyn Fn(f64) -> String> = if m == 0 {
            Box::new(|t: f64| {
                let a = 30.0 * (std::f64::consts::PI * t).sin();
                let c = 15.0 * (std::f64::consts::TAU * t).sin();
                format!("A{} C{}", f(a), f(c))
            })
        } else {
            Box::new(|t: f64| {
                let w = std::f64::consts::TAU * t;
                format!(
                    "A{} B{} C{}",
                    f(8.0 * w.sin()),
                    f(8.0 * w.cos() - 8.0),
                    f(5.0 * (2.0 * w).sin())
                )
            })
        };
        add("5axis", five_axis(FIVE_AXIS_SEGMENTS, 20.0, z, angles));
        let ball = [0.0, 0.0, z - 16.0];
        out.push(Program {
            name: format!("{tag}_probe"),
            machine: m,
            text: touches(ball, 6.0),
            events: false,
            lead_ticks: 0,
            probe: Some((ball, 6.0)),
            record: None,
            servo_bench: None,
        });
    }
    let (m, z, len) = (2, 275.0, HEXAPOD_XY_SINE_MM);
    let x0 = -len / 2.0;
    // The rapid to the sine's start, at the axes' 20 mm/s and 200 mm/s².
    let lead_s = -x0 / 20.0 + 20.0 / 200.0;
    let mut add = |what: &str, text: String| {
        out.push(Program {
            name: format!("hexapod_xy_{what}"),
            machine: m,
            text,
            events: what.ends_with("events"),
            lead_ticks: (lead_s * 1000.0) as u64,
            probe: None,
            record: None,
            servo_bench: None,
        })
    };
    add("seg0.05mm", sine(0.05, len, x0, z, 5.0, 40.0));
    add("events", sine(0.05, len, x0, z, 5.0, 40.0));
    add("helix-b", HELIX_B.into());
    add("helix-b-tilt", HELIX_B_TILT.into());
    let ball = [0.0, 0.0, 260.0];
    out.push(Program {
        name: "hexapod_xy_probe".into(),
        machine: m,
        text: touches(ball, 6.0),
        events: false,
        lead_ticks: 0,
        probe: Some((ball, 6.0)),
        record: None,
        servo_bench: None,
    });
    // The data recorder streaming 8 signals beside the job, every tick and every
    // servo period (whose 1 ms figure counts the servo interrupt staging 8 signals).
    for base in ["hexapod_xy_seg0.05mm", "hexapod_xy_helix-b-tilt"] {
        let Some(p) = out.iter().find(|p| p.name == base) else {
            continue;
        };
        let (machine, text, lead_ticks) = (p.machine, p.text.clone(), p.lead_ticks);
        for (tag, record, servo_bench) in [
            ("rec1k", record_tick(), None),
            ("rec10k", record_servo(), Some("pacer_hexapod_xy_8ch_rec8")),
        ] {
            out.push(Program {
                name: format!("{base}_{tag}"),
                machine,
                text: text.clone(),
                events: false,
                lead_ticks,
                probe: None,
                record: Some(record),
                servo_bench,
            });
        }
    }
    out
}

/// Report B's helix on the hexapod-xy, orientation held (the example program).
const HELIX_B: &str = include_str!("../../../examples/helix-b.ngc");
/// The same helix with the tool axis tilting ±10° (the example program).
const HELIX_B_TILT: &str = include_str!("../../../examples/helix-b-tilt.ngc");

/// X span of the sines, mm (about 113 mm of path).
pub const SINE_MM: f64 = 100.0;
/// X span of the hexapod-xy's sines, mm (about 102 mm of path): inside its table's
/// travel, whose ends (where the platform takes over) the planner approaches slowly
/// (the joint rates jump there).
pub const HEXAPOD_XY_SINE_MM: f64 = 90.0;
/// Arcs in the tangent chain (5 mm radius, 20° each: 1.75 mm of path per arc).
pub const ARCS: usize = 60;
/// Segments of the five-axis circle (20 mm radius: 1.05 mm each).
pub const FIVE_AXIS_SEGMENTS: usize = 120;
