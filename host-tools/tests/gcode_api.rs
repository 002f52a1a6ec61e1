//! The public face of the G-code front end: options, diagnostics, the tool table, and
//! the temporary block-returning form of `compile` that `job::compile_text` still uses.

use pkmc_host::gcode::canon::{Canon, Feed};
use pkmc_host::gcode::{compile, Diagnostic, Options, Tool, ToolTable, DEFAULT_ARC_TOLERANCE_NM};

#[test]
fn default_options_start_at_zero_with_a_two_micrometre_arc_tolerance() {
    let o = Options::default();
    assert_eq!(o.arc_tolerance_nm, 2_000);
    assert_eq!(DEFAULT_ARC_TOLERANCE_NM, 2_000);
    assert_eq!(o.start, [0; 6]);
    assert!(!o.block_delete);
    assert!(o.tools.is_empty());
}

#[test]
fn diagnostics_display_as_file_line_column_message() {
    let d = Diagnostic {
        file: "part.ngc".into(),
        line: 3,
        col: 7,
        kind: pkmc_host::gcode::ErrorKind::BadNumber,
        message: "division by zero".into(),
    };
    assert_eq!(d.to_string(), "part.ngc:3:7: division by zero");
}

#[test]
fn every_error_of_a_program_is_reported_and_nothing_is_produced() {
    let e = compile(
        "G1 X1 F1 (open\nG5 X1\nQ1\nG0 G1 X2\nG1 X1.2.3\nG0 X1",
        "t.ngc",
        &Options::default(),
    )
    .unwrap_err();
    let at: Vec<_> = e.iter().map(|d| (d.line, d.col)).collect();
    assert_eq!(at, vec![(1, 10), (2, 1), (3, 1), (4, 4), (5, 5)]);
    assert!(e[3].message.contains("modal group"));
}

#[test]
fn a_wider_arc_tolerance_accepts_a_radius_a_little_short_of_half_the_chord() {
    // R 3 µm short of half the chord: over the default 2 µm, within 5 µm (then a half
    // circle about the chord's middle).
    let program = "G0 X0 Y0\nG2 X20 Y0 R9.997 F100";
    assert!(compile(program, "t.ngc", &Options::default()).is_err());
    let loose = Options {
        arc_tolerance_nm: 5_000,
        ..Options::default()
    };
    let c = compile(program, "t.ngc", &loose).unwrap();
    assert!(
        matches!(
            c[1],
            Canon::Arc {
                center: [10_000_000, 0],
                ..
            }
        ),
        "{:?}",
        c[1]
    );
}

#[test]
fn a_centre_format_arc_is_held_to_linuxcnc_s_tolerances() {
    // 4 µm off on a 10 mm radius (an inch post's rounding) passes; 0.5 % off does not.
    let ok = "G0 X10 Y0\nG3 X0 Y10.004 I-10 F100";
    assert!(compile(ok, "t.ngc", &Options::default()).is_ok());
    let off = "G0 X10 Y0\nG3 X0 Y10.05 I-10 F100";
    assert!(compile(off, "t.ngc", &Options::default()).is_err());
}

#[test]
fn the_start_pose_is_where_incremental_moves_begin() {
    let o = Options {
        start: [1_000_000, 2_000_000, 3_000_000, 0, 0, 0],
        ..Options::default()
    };
    let c = compile("G91 G1 X1 F60", "t.ngc", &o).unwrap();
    assert_eq!(
        c[0],
        Canon::Linear {
            line: 1,
            target: [2_000_000, 2_000_000, 3_000_000, 0, 0, 0],
            feed: Feed::PerSecond(1_000_000),
        }
    );
}

#[test]
fn tool_table_entries_can_be_built_in_code() {
    let mut t = ToolTable::new();
    t.insert(
        4,
        Tool {
            offset: [0, 0, 50_000_000, 0, 0, 0],
            diameter_nm: 3_000_000,
        },
    );
    let o = Options {
        tools: t,
        ..Options::default()
    };
    let c = compile("T4 M6 G43\nG0 Z0", "t.ngc", &o).unwrap();
    assert_eq!(c.last().unwrap().target().unwrap()[2], 50_000_000);
}

#[test]
fn canonical_commands_become_protocol_blocks() {
    use pkmc::motion::block::Motion;
    let canon = compile(
        "G0 X1\nG1 Y2 F600\nG2 X2 Y3 I1 J0",
        "t.ngc",
        &Options::default(),
    )
    .unwrap();
    let blocks = pkmc_host::gcode::blocks::from_canon(&canon, [0; 6]).blocks;
    assert_eq!(blocks[0].motion, Motion::Rapid);
    assert_eq!(blocks[1].target[1], 2_000_000);
    assert_eq!(blocks[1].feed, 10_000_000);
    assert!(matches!(blocks[2].motion, Motion::Arc { .. }));
}

#[test]
fn an_axis_word_for_an_axis_the_machine_lacks_is_refused_at_its_column() {
    let xyz = Options {
        axes: [true, true, true, false, false, false],
        ..Options::default()
    };
    let errors = compile("G0 X1\nG0 Y2 C90 B4\nG92 A0\nG0 Z1", "t.ngc", &xyz).unwrap_err();
    let got: Vec<String> = errors.iter().map(|d| d.to_string()).collect();
    assert_eq!(
        got,
        [
            "t.ngc:2:7: C90: the machine has no C axis (its axes: X Y Z)",
            "t.ngc:3:5: A0: the machine has no A axis (its axes: X Y Z)",
        ]
    );
    assert!(compile("G0 A4", "t.ngc", &Options::default()).is_ok());
}

#[test]
fn lines_ending_in_cr_cr_lf_read_as_lines_a_cr_inside_a_line_is_still_an_error() {
    // Some posts and file transfers double the CR of a CRLF ending (issue 14).
    let unix = "G21 G90\nG1 X1 Y2 F100\nG0 Z3\nM2\n";
    let want = compile(unix, "t.ngc", &Options::default()).unwrap();
    for ending in ["\r\n", "\r\r\n", "\r\r\r\n"] {
        let text = unix.replace('\n', ending);
        assert_eq!(
            compile(&text, "t.ngc", &Options::default()).unwrap(),
            want,
            "{ending:?}"
        );
    }
    let e = compile("G1 X1\r F100\n", "t.ngc", &Options::default()).unwrap_err();
    assert_eq!((e[0].line, e[0].col), (1, 6));
    assert!(e[0].message.contains("U+000D"), "{}", e[0].message);
}
