//! A seeded generator of G-code programs for the `rs274` oracle (`rs274_oracle.rs`):
//! valid ones and, about one in four, one with a fault put in. Each program is about
//! one topic — arcs in the three planes (centre and radius format, helical, full
//! circles, extra turns), work offsets (G10 L2/L20, G54–G59.3, G92, G52, G53, tool
//! length offsets), units (G20/G21 mixed), canned cycles, cutter compensation (G41/G42,
//! G41.1/G42.1, on outlines of lines and arcs, some of which the tool cannot follow),
//! parameters and expressions, O-words — and ends with M2. What the program should
//! give is not decided here: LinuxCNC's interpreter says it.
//!
//! Numbers are written with at most 4 decimals. The generator follows the current
//! point in program coordinates so that centre-format arcs end on their circle (to
//! the rounding of the written numbers) and radius-format ones are reachable; after
//! anything that moves the program's origin it rapids to an absolute point to know
//! where it is again.

use std::f64::consts::TAU;
use std::fmt::Write as _;

/// splitmix64: small, seeded, the same on every platform.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// 0 ≤ n < `k`.
    pub fn below(&mut self, k: usize) -> usize {
        (self.next() % k as u64) as usize
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }

    pub fn chance(&mut self, p: f64) -> bool {
        self.range(0.0, 1.0) < p
    }

    pub fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[self.below(items.len())]
    }
}

/// One generated program.
pub struct Generated {
    /// `gen-0042-arcs`, `gen-0043-cycles-fault`, …
    pub name: String,
    pub text: String,
}

/// A number as written in a program: at most 4 decimals, no trailing zeros.
pub fn num(v: f64) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    match s {
        "-0" | "" => "0".to_string(),
        s => s.to_string(),
    }
}

fn round4(v: f64) -> f64 {
    (v * 1e4).round() / 1e4
}

/// The letters of the axes and of the centre offsets.
const AXIS: [char; 3] = ['X', 'Y', 'Z'];
const OFFSET: [char; 3] = ['I', 'J', 'K'];

/// Plane code and its (first, second, helix) axes.
const PLANES: [(u8, [usize; 3]); 3] = [(17, [0, 1, 2]), (18, [2, 0, 1]), (19, [1, 2, 0])];

/// The program being written and where it stands.
struct Gen<'r> {
    rng: &'r mut Rng,
    out: String,
    /// The current point in program coordinates and units.
    pos: [f64; 3],
    inch: bool,
    incremental: bool,
}

impl Gen<'_> {
    fn line(&mut self, s: &str) {
        self.out.push_str(s);
        self.out.push('\n');
    }

    /// Millimetres in the program's units.
    fn mm(&self, v: f64) -> f64 {
        if self.inch {
            v / 25.4
        } else {
            v
        }
    }

    /// A length of `lo`–`hi` mm in program units, rounded as written.
    fn len(&mut self, lo: f64, hi: f64) -> f64 {
        let v = self.rng.range(lo, hi);
        round4(self.mm(v))
    }

    fn units(&mut self, inch: bool) {
        self.inch = inch;
        self.line(if inch { "G20" } else { "G21" });
    }

    fn distance(&mut self, incremental: bool) {
        self.incremental = incremental;
        self.line(if incremental { "G91" } else { "G90" });
    }

    /// Axis words moving to `to` (program coordinates) from the current point, in the
    /// distance mode in force; only the axes in `which`.
    fn axis_words(&self, to: [f64; 3], which: &[usize]) -> String {
        let mut s = String::new();
        for &a in which {
            let v = if self.incremental {
                round4(to[a] - self.pos[a])
            } else {
                to[a]
            };
            write!(s, " {}{}", AXIS[a], num(v)).unwrap();
        }
        s
    }

    /// A rapid to an absolute point, so the generator knows the current point again.
    fn resync(&mut self) {
        let to = [
            self.len(-60.0, 60.0),
            self.len(-60.0, 60.0),
            self.len(0.0, 30.0),
        ];
        let words = format!(" X{} Y{} Z{}", num(to[0]), num(to[1]), num(to[2]));
        self.line(&format!("G90 G0{words}"));
        self.incremental = false;
        self.pos = to;
    }

    /// A straight move (G0 or G1) to a random nearby point.
    fn straight(&mut self, code: &str) {
        let mut to = self.pos;
        let n = 1 + self.rng.below(3);
        let mut which: Vec<usize> = (0..3).collect();
        while which.len() > n {
            which.remove(self.rng.below(which.len()));
        }
        for &a in &which {
            to[a] = round4(self.pos[a] + self.len(-40.0, 40.0));
        }
        let words = self.axis_words(to, &which);
        self.line(&format!("{code}{words}"));
        self.pos = to;
    }

    /// One arc in `plane` from the current point; `fault` puts a mistake in it.
    fn arc(&mut self, plane: usize, fault: bool) {
        let [p, q, h] = PLANES[plane].1;
        let code = if self.rng.chance(0.5) { "G2" } else { "G3" };
        let start = self.pos;
        let mut end = start;
        let mut words;
        let kind = self.rng.below(5);
        if kind == 4 {
            // Radius format: a chord and a radius at least half of it.
            let d = self.len(1.0, 60.0);
            let t = self.rng.range(0.0, TAU);
            end[p] = round4(start[p] + d * t.cos());
            end[q] = round4(start[q] + d * t.sin());
            let chord = (end[p] - start[p]).hypot(end[q] - start[q]);
            let k = if fault {
                0.4
            } else {
                self.rng.range(0.52, 3.0)
            };
            let r = round4(chord * k) * if self.rng.chance(0.5) { 1.0 } else { -1.0 };
            words = self.axis_words(end, &[p, q]);
            write!(words, " R{}", num(r)).unwrap();
        } else {
            let r = self.len(0.5, 50.0);
            let a0 = self.rng.range(0.0, TAU);
            let offset = [round4(-r * a0.cos()), round4(-r * a0.sin())];
            let centre = [start[p] + offset[0], start[q] + offset[1]];
            let radius = offset[0].hypot(offset[1]);
            if kind != 3 {
                // kind 3: a full circle, the end at the start.
                let a1 = a0 + self.rng.range(-TAU, TAU);
                end[p] = round4(centre[0] + radius * a1.cos());
                end[q] = round4(centre[1] + radius * a1.sin());
            }
            if fault {
                end[p] = round4(end[p] + self.mm(1.0));
            }
            words = self.axis_words(end, &[p, q]);
            let absolute = self.rng.chance(0.15);
            let (i, j) = if absolute {
                (round4(centre[0]), round4(centre[1]))
            } else {
                (offset[0], offset[1])
            };
            write!(words, " {}{} {}{}", OFFSET[p], num(i), OFFSET[q], num(j)).unwrap();
            if absolute {
                words = format!(" G90.1{words}");
            }
            if kind == 3 && self.rng.chance(0.5) {
                write!(words, " P{}", 1 + self.rng.below(3)).unwrap();
            }
        }
        if kind == 2 || self.rng.chance(0.2) {
            // Helical.
            end[h] = round4(start[h] + self.len(-10.0, 10.0));
            words.push_str(&self.axis_words(end, &[h]));
        }
        self.line(&format!("{code}{words}"));
        if words.contains("G90.1") {
            self.line("G91.1");
        }
        self.pos = end;
    }

    fn feed(&mut self) {
        let f = if self.inch { 20.0 } else { 500.0 };
        let l = format!("F{}", num(f * self.rng.range(0.5, 2.0)));
        self.line(&l);
    }

    fn header(&mut self) {
        let mut h = vec!["G17", "G40", "G49", "G80", "G90", "G94"];
        h.retain(|_| self.rng.chance(0.7));
        let units = if self.rng.chance(0.3) { "G20" } else { "G21" };
        self.inch = units == "G20";
        h.insert(0, units);
        self.line(&h.join(" "));
        self.feed();
        self.resync();
    }
}

/// Arcs in the three planes.
fn arcs(g: &mut Gen, fault: bool) {
    let n = 1 + g.rng.below(4);
    let bad = g.rng.below(n);
    for k in 0..n {
        let plane = g.rng.below(3);
        g.line(&format!("G{}", PLANES[plane].0));
        if g.rng.chance(0.3) {
            let incremental = !g.incremental;
            g.distance(incremental);
        }
        if g.rng.chance(0.3) {
            g.straight("G1");
        }
        g.arc(plane, fault && k == bad);
    }
    g.line("G17 G90");
    g.incremental = false;
}

/// Work offsets, G92, G52, G53 and tool length offsets, with moves and an arc under
/// them.
fn offsets(g: &mut Gen, fault: bool) {
    for _ in 0..1 + g.rng.below(4) {
        match g.rng.below(8) {
            0 | 1 => {
                let p = 1 + g.rng.below(9);
                let (x, y, z) = (g.len(-80.0, 80.0), g.len(-80.0, 80.0), g.len(-20.0, 20.0));
                g.line(&format!("G10 L2 P{p} X{} Y{} Z{}", num(x), num(y), num(z)));
                let sys = [
                    "G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3",
                ];
                g.line(sys[p - 1]);
            }
            2 => {
                let (x, y) = (g.len(-50.0, 50.0), g.len(-50.0, 50.0));
                g.line(&format!("G92 X{} Y{}", num(x), num(y)));
            }
            3 => {
                let l = g.rng.pick(&["G92.1", "G92.2", "G92.3"]);
                g.line(l);
            }
            4 => {
                let (x, z) = (g.len(-30.0, 30.0), g.len(-5.0, 5.0));
                g.line(&format!("G52 X{} Z{}", num(x), num(z)));
            }
            5 => {
                let (x, y) = (g.len(-100.0, 100.0), g.len(-100.0, 100.0));
                let code = g.rng.pick(&["G0", "G1"]);
                g.line(&format!("G53 {code} X{} Y{}", num(x), num(y)));
            }
            6 => {
                let t = 5 + g.rng.below(4);
                g.line(&format!("T{t} M6"));
                let l = g.rng.pick(&["G43", "G43 H7", "G49"]);
                g.line(l);
            }
            _ => {
                let (x, y) = (g.len(-40.0, 40.0), g.len(-40.0, 40.0));
                g.line(&format!("G10 L20 P0 X{} Y{}", num(x), num(y)));
            }
        }
        g.resync();
        g.straight("G1");
        if g.rng.chance(0.5) {
            g.arc(0, false);
        }
    }
    if fault {
        let l = g
            .rng
            .pick(&["G10 L2 P10 X1", "G92", "G53 G2 X1 Y1 R5", "G43 H100"]);
        g.line(l);
    }
}

/// Inches and millimetres mixed, with moves, arcs and feeds.
fn units(g: &mut Gen, fault: bool) {
    for _ in 0..2 + g.rng.below(4) {
        let inch = !g.inch;
        g.units(inch);
        // Switching units leaves the current point in the old units: say where it is.
        g.resync();
        if g.rng.chance(0.5) {
            g.feed();
        }
        if g.rng.chance(0.3) {
            g.distance(true);
        }
        g.straight("G1");
        if g.rng.chance(0.5) {
            g.arc(0, false);
        }
        g.distance(false);
    }
    if fault {
        let l = g.rng.pick(&["G20 G21 X1", "G1 X1 G0 Y1", "G1 F-5 X1"]);
        g.line(l);
    }
}

/// Canned cycles in the three planes.
fn cycles(g: &mut Gen, fault: bool) {
    let plane = if g.rng.chance(0.6) { 0 } else { g.rng.below(3) };
    let (code, [p, q, h]) = PLANES[plane];
    g.line(&format!("G{code}"));
    // Up at the initial level.
    let mut to = g.pos;
    to[h] = g.len(10.0, 30.0);
    let words = g.axis_words(to, &[h]);
    g.line(&format!("G0{words}"));
    g.pos = to;
    let cycle = g.rng.pick(&[81, 82, 83, 73, 85, 89, 81, 83, 84, 86]);
    if matches!(cycle, 84 | 86) || g.rng.chance(0.2) {
        // LinuxCNC's G84 and G86 need the spindle turning.
        g.line("S1000 M3");
    }
    let l = g.rng.pick(&["G98", "G99"]);
    g.line(l);
    let r = g.len(1.0, 8.0);
    let bottom = if fault && g.rng.chance(0.5) {
        r + g.mm(3.0)
    } else {
        -g.len(0.5, 20.0)
    };
    let mut line = format!("G{cycle}");
    let mut at = g.pos;
    at[p] = g.len(-50.0, 50.0);
    at[q] = g.len(-50.0, 50.0);
    at[h] = round4(bottom);
    line.push_str(&g.axis_words(at, &[p, q, h]));
    write!(line, " R{}", num(r)).unwrap();
    if matches!(cycle, 83 | 73) && !(fault && g.rng.chance(0.5)) {
        write!(line, " Q{}", num(g.len(0.5, 6.0))).unwrap();
    }
    if matches!(cycle, 82 | 89 | 86) {
        write!(line, " P{}", num(g.rng.range(0.0, 1.0))).unwrap();
    }
    if fault && g.rng.chance(0.3) {
        line.push_str(" A10");
    }
    g.line(&line);
    for _ in 0..g.rng.below(4) {
        let (a, b) = (g.len(-50.0, 50.0), g.len(-50.0, 50.0));
        g.line(&format!("{}{} {}{}", AXIS[p], num(a), AXIS[q], num(b)));
    }
    if g.rng.chance(0.3) {
        // Repeats, incremental: the hole moves by X Y each time.
        g.distance(true);
        let (a, b) = (g.len(-10.0, 10.0), g.len(-10.0, 10.0));
        let l = 2 + g.rng.below(3);
        g.line(&format!("{}{} {}{} L{l}", AXIS[p], num(a), AXIS[q], num(b)));
        g.distance(false);
    }
    g.line("G80 G17");
    g.resync();
}

/// Cutter compensation on an outline of lines and arcs in XY.
fn compensation(g: &mut Gen, fault: bool) {
    g.line("G17");
    let side = g.rng.pick(&["G41", "G42"]);
    let tool = 1 + g.rng.below(4);
    let on = match g.rng.below(3) {
        0 => format!("{side} D{tool}"),
        1 => {
            g.line(&format!("T{tool} M6"));
            side.to_string()
        }
        _ => format!("{side}.1 D{}", num(g.len(0.5, 8.0))),
    };
    // The entry: a long move away.
    let mut to = g.pos;
    to[0] = round4(g.pos[0] + g.len(20.0, 40.0) * if g.rng.chance(0.5) { 1.0 } else { -1.0 });
    to[1] = round4(g.pos[1] + g.len(20.0, 40.0));
    let words = g.axis_words(to, &[0, 1]);
    g.line(&format!("{on} G1{words}"));
    g.pos = to;
    for _ in 0..2 + g.rng.below(5) {
        match g.rng.below(5) {
            0 | 1 => {
                let mut to = g.pos;
                to[0] = round4(g.pos[0] + g.len(-30.0, 30.0));
                to[1] = round4(g.pos[1] + g.len(-30.0, 30.0));
                let words = g.axis_words(to, &[0, 1]);
                g.line(&format!("G1{words}"));
                g.pos = to;
            }
            2 => {
                // A Z move on its own.
                let mut to = g.pos;
                to[2] = round4(g.pos[2] + g.len(-3.0, 3.0));
                let words = g.axis_words(to, &[2]);
                g.line(&format!("G1{words}"));
                g.pos = to;
            }
            _ => g.arc(0, false),
        }
    }
    if fault {
        g.line("G40");
        g.arc(0, false);
    } else {
        g.line("G40");
        g.straight("G1");
    }
    g.resync();
}

/// Parameters: numbered, named (local and global), expressions and functions.
fn parameters(g: &mut Gen, fault: bool) {
    let a = g.len(1.0, 30.0);
    let b = g.len(1.0, 30.0);
    g.line(&format!("#1 = {}", num(a)));
    let l = format!("#<len> = [#1 * {} + 2]", num(g.rng.range(0.1, 2.0)));
    g.line(&l);
    g.line(&format!("#<_glob> = {}", num(b)));
    g.line(&format!("#2 = [SQRT[#1 * #1 + {}] / 2]", num(b * b)));
    let exprs = [
        "[#1 + #2]",
        "[#<len> * COS[30]]",
        "[#<_glob> * SIN[#1 * 10]]",
        "[ATAN[#2]/[#1] / 10]",
        "[FIX[#<len>] - FUP[#2] + ROUND[#1]]",
        "[#1 MOD 7 - ABS[-#2] / 3]",
        "[2 ** 3 - #2 / [1 + #1]]",
        "[[#1 GT #2] * 5 + [#1 LE #2] * 3]",
        "-[#<len> / 2]",
        "#[1 + 1]",
        "[EXP[1] + LN[#1]]",
    ];
    for _ in 0..2 + g.rng.below(4) {
        let (x, y) = (g.rng.pick(&exprs), g.rng.pick(&exprs));
        g.line(&format!("G1 X{x} Y{y}"));
    }
    g.line("#3 = #1 #1 = [#3 + 1] G0 X#1 Y#3");
    if fault {
        let l = g.rng.pick(&[
            "G1 X#<undefined>",
            "G1 X[1 / 0]",
            "G1 X[SQRT[-1]]",
            "G1 X[ACOS[2]]",
            "G1 X[1 +]",
            "#<_x> = 1",
            "G1 X#6000",
        ]);
        g.line(l);
    }
    g.resync();
}

/// O-words: a subroutine with arguments, if/elseif/else, while, repeat, do, break.
fn owords(g: &mut Gen, fault: bool) {
    let step = g.len(1.0, 5.0);
    let radius = g.len(2.0, 10.0);
    g.line("o100 sub");
    g.line("  G91 G1 X#1 Y#2");
    g.line("  G90");
    g.line("  o101 if [#1 GT #2]");
    g.line("    G91 G1 Y[#2 / 2]");
    g.line("  o101 elseif [#1 EQ #2]");
    g.line("    G91 G1 X-#1");
    g.line("  o101 else");
    g.line("    G91 G2 X0 Y0 I[#3] J0");
    g.line("  o101 endif");
    g.line("  G90");
    g.line("o100 endsub [#1 + #2]");
    g.line("o<square> sub");
    g.line("  G91 G1 X#1");
    g.line("  G1 Y#1");
    g.line("  G1 X-#1");
    g.line("  G1 Y-#1");
    g.line("  G90");
    g.line("o<square> return");
    g.line("o<square> endsub");
    // LinuxCNC 2.9 runs a do-while loop only once after a `break` it skipped, and
    // ignores a `break` after a loop left through `continue` (docs/gcode.md): most
    // programs have only one of `break` and `continue`, the do loop first; one in ten
    // has both, in either order.
    let (with_break, with_continue, do_first) = match g.rng.below(20) {
        0 => (true, true, true),
        1 => (true, true, false),
        k => (k % 2 == 0, k % 2 == 1, true),
    };
    if do_first {
        do_loop(g, with_continue);
    }
    let n = 1 + g.rng.below(4);
    g.line("#10 = 0");
    g.line(&format!("o200 while [#10 LT {n}]"));
    let second = g.len(1.0, 5.0);
    g.line(&format!(
        "  o100 call [{} * [#10 + 1]] [{}] [{}]",
        num(step),
        num(second),
        num(radius)
    ));
    g.line("  #10 = [#10 + 1]");
    let l = format!("  o201 if [#10 EQ {}]", g.rng.below(5));
    g.line(&l);
    g.line(if with_break {
        "    o200 break"
    } else {
        "    #12 = 1"
    });
    g.line("  o201 endif");
    g.line("o200 endwhile");
    let l = format!("o300 repeat [{}]", 1 + g.rng.below(3));
    g.line(&l);
    let l = format!("  o<square> call [{}]", num(g.len(1.0, 10.0)));
    g.line(&l);
    g.line("o300 endrepeat");
    if !do_first {
        do_loop(g, with_continue);
    }
    if fault {
        let l = g.rng.pick(&[
            "o500 call",
            "o600 if [1]",
            "o100 endsub",
            "o700 while [1]\no701 endwhile",
            "o800 if [1]\no800 endif\no800 if [1]\no800 endif",
        ]);
        g.line(l);
    }
    g.resync();
}

/// A do-while loop (with a `continue` or not), moving by the last subroutine's return
/// value.
fn do_loop(g: &mut Gen, with_continue: bool) {
    g.line("#11 = 0");
    g.line("o400 do");
    g.line("  #11 = [#11 + 1]");
    g.line("  o401 if [#11 EQ 2]");
    g.line(if with_continue {
        "    o400 continue"
    } else {
        "    #13 = 1"
    });
    g.line("  o401 endif");
    g.line("  G91 G0 Z[#<_value> / 10]");
    g.line("  G90");
    let l = format!("o400 while [#11 LT {}]", 1 + g.rng.below(4));
    g.line(&l);
}

/// A fault that fits any program, put before M2.
fn any_fault(g: &mut Gen) {
    let l = g.rng.pick(&[
        "G1 X1 X2",
        "G0 G1 X1",
        "G2 X5",
        "G17 G18",
        "G1 X1 Y2 K3",
        "M3 M4",
        "G1 X[1",
        "G0 X1 (comment",
        "G93 G1 X1",
        "G2 X1 Y1 I1 J1 R1",
    ]);
    g.line(l);
}

type Topic = (&'static str, fn(&mut Gen, bool));

const TOPICS: [Topic; 7] = [
    ("arcs", arcs),
    ("offsets", offsets),
    ("units", units),
    ("cycles", cycles),
    ("compensation", compensation),
    ("parameters", parameters),
    ("owords", owords),
];

/// `n` programs from `seed`: topics in turn, about one in four with a fault.
pub fn generate(seed: u64, n: usize) -> Vec<Generated> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|k| {
            let (topic, body) = TOPICS[k % TOPICS.len()];
            let fault = rng.chance(0.25);
            let mut g = Gen {
                rng: &mut rng,
                out: String::new(),
                pos: [0.0; 3],
                inch: false,
                incremental: false,
            };
            g.header();
            let anywhere = fault && g.rng.chance(0.2);
            body(&mut g, fault && !anywhere);
            if anywhere {
                any_fault(&mut g);
            }
            g.line("M2");
            Generated {
                name: format!("gen-{k:04}-{topic}{}", if fault { "-fault" } else { "" }),
                text: g.out,
            }
        })
        .collect()
}
