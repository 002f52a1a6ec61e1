//! Report B's contour study as a regression test: the helix on the `seed-b` machine,
//! plants 10 % off the models and a periodic cutting force, under the four controllers
//! that share the same PID gains (see `docs/contour.md`). Runs in simulated time.

use pkmc_host::contour_study::{run_study, Scheme};

#[test]
fn ccpm_keeps_the_contour_error_below_a_tenth_of_uncoupled_and_below_feed_forward() {
    let r = run_study().unwrap();
    let max = |s: Scheme| r.iter().find(|x| x.scheme == s).unwrap().max_mm;
    for x in &r {
        assert!(
            x.trip.is_none(),
            "{} tripped: {:?}",
            x.scheme.name(),
            x.trip
        );
        assert_eq!(x.saturated_periods, 0, "{} saturated", x.scheme.name());
    }
    let (us, ff, ccs, ccpm) = (
        max(Scheme::Uncoupled),
        max(Scheme::FeedForward),
        max(Scheme::CrossCoupled),
        max(Scheme::Ccpm),
    );
    assert!(
        ccpm <= us / 10.0,
        "CCPM {:.2} um against uncoupled {:.2} um",
        ccpm * 1e3,
        us * 1e3
    );
    assert!(
        ccpm < ff,
        "CCPM {:.2} um against feed-forward {:.2} um",
        ccpm * 1e3,
        ff * 1e3
    );
    assert!(
        ccs < us,
        "cross-coupled {:.2} um against uncoupled {:.2} um",
        ccs * 1e3,
        us * 1e3
    );
}

#[test]
fn every_scheme_measures_the_whole_ten_seconds_of_the_report_s_helix() {
    let r = run_study().unwrap();
    for x in &r {
        assert_eq!(x.trace.len(), 10_001, "{}", x.scheme.name()); // t = 0 ..= 10 s
        assert!(x.rms_mm > 0.0 && x.rms_mm <= x.max_mm);
    }
}
