//! Every program in `tests/fixtures/gcode/*.ngc` is a test: it is compiled and the
//! result compared with its sibling `.expect` file, which holds either the canonical
//! commands in the text form of [`listing`] (one per line) or the diagnostics, one per
//! line as `file:line:col: message`.
//!
//! Conventions: a sibling `.tools` file is the tool table (LinuxCNC tool-file form); a
//! first line `; fixture: block-delete` turns the block-delete switch on. Set
//! `BLESS=1` to (re)write the `.expect` files from the current output, then review
//! them. `every_fixture_file_has_a_test` fails when a fixture is not listed below.

use pkmc_host::gcode::canon::{Canon, Coolant, Feed, PathMode, Plane, Spindle};
use pkmc_host::gcode::{compile, Options, ToolTable};
use std::fmt::Write;
use std::path::PathBuf;

fn dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/gcode")
}

/// Axis units as user units: nm as mm, n° as degrees, exactly.
fn user(v: i64, per: u64) -> String {
    let sign = if v < 0 { "-" } else { "" };
    let a = v.unsigned_abs();
    let (whole, frac) = (a / per, a % per);
    if frac == 0 {
        return format!("{sign}{whole}");
    }
    let width = per.ilog10() as usize;
    let f = format!("{frac:0width$}");
    format!("{sign}{whole}.{}", f.trim_end_matches('0'))
}

fn pose(t: &[i64; 6]) -> String {
    let names = ["X", "Y", "Z", "A", "B", "C"];
    let mut s = String::new();
    for (i, v) in t.iter().enumerate() {
        let per = if i < 3 { 1_000_000 } else { 1_000_000_000 };
        let _ = write!(s, "{}{} ", names[i], user(*v, per));
    }
    s.pop();
    s
}

/// A spline's control point offset: X and Y, and any other axis that is not zero.
fn offset(t: &[i64; 6]) -> String {
    let full = pose(t);
    full.split(' ')
        .enumerate()
        .filter(|(i, word)| *i < 2 || !word[1..].eq("0"))
        .map(|(_, word)| word)
        .collect::<Vec<_>>()
        .join(" ")
}

fn feed(f: &Feed) -> String {
    match f {
        Feed::PerSecond(v) => format!("F{v}/s"),
        Feed::InverseTime(us) => format!("T{us}us"),
    }
}

/// One command as a line of text.
fn listing(c: &Canon) -> String {
    let body = match c {
        Canon::Rapid { target, .. } => format!("rapid {}", pose(target)),
        Canon::Linear {
            target, feed: f, ..
        } => format!("linear {} {}", pose(target), feed(f)),
        Canon::Arc {
            target,
            center,
            plane,
            clockwise,
            turns,
            feed: f,
            ..
        } => format!(
            "arc {} centre {} {} {} {} turns {} {}",
            pose(target),
            user(center[0], 1_000_000),
            user(center[1], 1_000_000),
            match plane {
                Plane::Xy => "XY",
                Plane::Zx => "ZX",
                Plane::Yz => "YZ",
            },
            if *clockwise { "cw" } else { "ccw" },
            turns,
            feed(f)
        ),
        Canon::Cubic {
            target,
            c1,
            c2,
            feed: f,
            ..
        } => format!(
            "cubic {} c1 {} c2 {} {}",
            pose(target),
            offset(c1),
            offset(c2),
            feed(f)
        ),
        Canon::Quadratic {
            target, c, feed: f, ..
        } => format!("quadratic {} c {} {}", pose(target), offset(c), feed(f)),
        Canon::Probe {
            target,
            feed: f,
            probing,
            ..
        } => format!("probe {} {} {}", probing.name(), pose(target), feed(f)),
        Canon::Dwell { ms, .. } => format!("dwell {ms}ms"),
        Canon::PathMode { mode, .. } => match mode {
            PathMode::ExactStop => "path exact-stop".into(),
            PathMode::Blend(None) => "path blend".into(),
            PathMode::Blend(Some(nm)) => format!("path blend {}", user(*nm, 1_000_000)),
        },
        Canon::Spindle { state, .. } => match state {
            Spindle::Off => "spindle off".into(),
            Spindle::Clockwise(r) => format!("spindle cw {r}"),
            Spindle::CounterClockwise(r) => format!("spindle ccw {r}"),
        },
        Canon::Coolant { state, .. } => match state {
            Coolant::Mist => "coolant mist".into(),
            Coolant::Flood => "coolant flood".into(),
            Coolant::Off => "coolant off".into(),
        },
        Canon::ToolChange { tool, .. } => format!("tool-change {tool}"),
        Canon::Pause { optional, .. } => {
            if *optional {
                "pause optional".into()
            } else {
                "pause".into()
            }
        }
        Canon::Message { text, .. } => format!("message {text:?}"),
        Canon::End { .. } => "end".into(),
    };
    format!("{}: {body}", c.line())
}

fn check(name: &str) {
    let path = dir().join(format!("{name}.ngc"));
    let source = std::fs::read_to_string(&path).expect("fixture readable");
    let mut options = Options::default();
    if source.starts_with("; fixture: block-delete") {
        options.block_delete = true;
    }
    let tools = dir().join(format!("{name}.tools"));
    if tools.exists() {
        let text = std::fs::read_to_string(&tools).unwrap();
        options.tools = ToolTable::parse(&text, &format!("{name}.tools")).unwrap();
    }
    let file = format!("{name}.ngc");
    let got: String = match compile(&source, &file, &options) {
        Ok(commands) => commands.iter().map(|c| listing(c) + "\n").collect(),
        Err(errors) => errors.iter().map(|d| format!("{d}\n")).collect(),
    };
    let expect_path = dir().join(format!("{name}.expect"));
    if std::env::var_os("BLESS").is_some() {
        std::fs::write(&expect_path, &got).unwrap();
        return;
    }
    let want = std::fs::read_to_string(&expect_path)
        .unwrap_or_else(|_| panic!("{name}.expect missing (run with BLESS=1 to create it)"));
    assert!(
        got == want,
        "{name}: output differs from {name}.expect\n--- got\n{got}--- expected\n{want}"
    );
}

macro_rules! fixtures {
    ($($name:ident),* $(,)?) => {
        $(
            #[test]
            fn $name() {
                check(stringify!($name));
            }
        )*
        const NAMES: &[&str] = &[$(stringify!($name)),*];
    };
}

fixtures!(
    // Features.
    straight_moves_in_mm_convert_exactly,
    inch_and_incremental_moves_convert_exactly,
    spaces_case_and_comments_are_free,
    messages_become_commands,
    percent_lines_delimit_the_program,
    block_delete_off_runs_slashed_lines,
    block_delete_on_skips_slashed_lines,
    a_matching_checksum_is_accepted,
    arcs_with_centres_full_circles_helices_and_turns,
    arcs_with_radii_take_the_short_or_long_way,
    arcs_in_the_zx_and_yz_planes,
    arc_centres_can_be_absolute,
    dwell_and_path_modes,
    spindle_coolant_tool_change_pauses_and_end,
    work_offsets_from_g10_and_g54_to_g59,
    g92_offsets_set_clear_and_restore,
    g28_and_g30_go_home_through_the_intermediate_point,
    g53_moves_in_machine_coordinates,
    tool_length_offsets_from_the_tool_table,
    parameters_and_expressions,
    parameter_settings_take_effect_after_the_line,
    drilling_cycles_g81_with_g98_and_g99,
    peck_drilling_g83_and_g73,
    dwell_and_boring_cycles_g82_g85_g89,
    incremental_cycles_repeat_with_l,
    polar_coordinates_absolute_and_incremental,
    inverse_time_feeds,
    rotary_only_moves_feed_in_degrees,
    // Errors.
    modal_group_conflicts_are_errors,
    arc_ending_off_the_circle_is_rejected_with_its_line,
    arc_without_a_centre_or_radius_is_rejected,
    radius_arcs_cannot_be_full_circles_or_too_small,
    feed_moves_without_a_feed_are_rejected,
    unknown_words_and_codes_are_rejected,
    malformed_numbers_are_rejected,
    unclosed_comments_and_brackets_are_rejected,
    control_characters_are_rejected_at_their_column,
    overlong_lines_are_rejected,
    unknown_parameters_are_rejected,
    division_by_zero_and_domain_errors_are_rejected,
    numbers_too_large_are_rejected,
    unsupported_features_are_refused_by_name,
    checksum_mismatch_is_rejected,
    words_no_code_uses_are_rejected,
    unclosed_percent_is_rejected,
    canned_cycle_mistakes_are_rejected,
    offset_and_tool_mistakes_are_rejected,
    // Issue 14: as CAM posts and LinuxCNC write it.
    a_safety_line_with_g80_and_a_motion_code_is_accepted,
    fractional_s_and_f0_where_nothing_moves_at_feed_are_accepted,
    a_feed_move_at_f0_is_rejected_there,
    exists_takes_numbered_and_named_parameters,
    exists_reads_an_indirect_parameter_number,
    a_parameter_number_may_be_a_function_call,
    g64_r_planner_mode_is_refused_by_name,
    codes_linuxcnc_or_posts_know_are_refused_by_name,
    a_refused_arc_ends_where_programmed_so_later_lines_are_not_refused_too,
    predefined_and_ini_parameters_are_read_only,
    coordinates_without_a_motion_mode_are_rejected,
    g52_local_offsets_share_g92s_registers,
    g43_1_takes_the_tool_length_from_the_line,
    g10_l1_l10_l11_rewrite_the_tool_table_for_the_run,
    tool_table_edits_and_local_offsets_are_checked,
    cutter_compensation_offsets_the_outline_rounds_outside_corners_and_trims_inside_ones,
    cutter_compensation_mistakes_are_rejected,
    tool_offsets_along_every_axis_shift_the_program,
    debug_comments_show_parameters_in_their_format,
    // O-word subroutines and control flow.
    subroutine_arguments_are_local_and_restored_on_return,
    named_subroutines_have_their_own_local_named_parameters,
    subroutines_return_values_and_may_recurse,
    if_elseif_and_else_run_exactly_one_branch,
    while_do_while_and_repeat_loops_repeat_their_bodies,
    break_and_continue_leave_or_restart_their_loop,
    m2_inside_a_subroutine_ends_the_program,
    o_word_lines_take_n_numbers_comments_and_any_case,
    unmatched_and_unterminated_o_word_blocks_are_rejected,
    calls_to_undefined_subroutines_are_rejected,
    return_break_and_continue_outside_their_blocks_are_rejected,
    calls_nested_more_than_ten_deep_are_rejected,
    a_subroutine_is_called_only_after_its_definition,
    an_endless_loop_stops_with_an_error_at_its_line,
    errors_in_loops_and_subroutines_are_reported_once_per_line,
    a_post_s_program_name_line_is_ignored,
    a_peck_cycle_without_any_q_given_is_refused_after_a_failed_line,
    coordinate_rotation_turns_moves_arcs_and_offsets,
    rotated_systems_refuse_other_planes_and_cycles_by_name,
    // G5 and G5.1 splines.
    cubic_splines_continue_a_series_with_mirrored_control_points,
    splines_in_inches_and_incremental_distances,
    splines_turn_with_a_rotated_coordinate_system,
    spline_mistakes_are_rejected,
);

#[test]
fn every_fixture_file_has_a_test() {
    for entry in std::fs::read_dir(dir()).unwrap() {
        let path = entry.unwrap().path();
        let stem = path.file_stem().unwrap().to_string_lossy().into_owned();
        let ext = path.extension().map(|e| e.to_string_lossy().into_owned());
        assert!(
            NAMES.contains(&stem.as_str()),
            "fixture {} is not listed in gcode_fixtures.rs",
            path.display()
        );
        if ext.as_deref() == Some("ngc") {
            assert!(
                dir().join(format!("{stem}.expect")).exists(),
                "{stem}.ngc has no .expect"
            );
        }
    }
}
