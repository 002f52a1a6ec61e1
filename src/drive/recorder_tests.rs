use super::*;

fn setup(ids: &[u8], decimate: u16, trigger: Trigger, pre: u16) -> Setup {
    let mut signals = [0; MAX_SIGNALS];
    signals[..ids.len()].copy_from_slice(ids);
    Setup {
        signals,
        count: ids.len() as u8,
        servo: false,
        decimate,
        trigger,
        pre,
    }
}

fn recorder() -> Recorder {
    let mut r = Recorder::new();
    // The same as `new`, written in place.
    unsafe { Recorder::init_at(&mut r) };
    r
}

/// The finished capture's samples, each as its signals' values.
fn samples(r: &Recorder) -> Vec<Vec<i32>> {
    let c = r.capture();
    let mut bytes = vec![0; c.samples as usize * c.width as usize];
    // Read in odd pieces, so that the pieces' joins and the ring's wrap are crossed.
    let mut at = 0;
    while at < bytes.len() {
        let end = (at + 7).min(bytes.len());
        assert_eq!(r.read(at, &mut bytes[at..end]), end - at);
        at = end;
    }
    assert_eq!(r.read(bytes.len(), &mut [0; 4]), 0);
    bytes
        .chunks(c.width as usize)
        .map(|s| {
            let mut out = Vec::new();
            let mut i = 0;
            for sig in r.signals().iter().map(|&id| Signal::from_id(id).unwrap()) {
                if sig.width() == 2 {
                    out.push(i16::from_le_bytes([s[i], s[i + 1]]) as i32);
                } else {
                    out.push(i32::from_le_bytes(s[i..i + 4].try_into().unwrap()));
                }
                i += sig.width() as usize;
            }
            out
        })
        .collect()
}

fn values(v: i32) -> [i32; MAX_SIGNALS] {
    [v, -v, 2 * v, 0, 0, 0, 0, 0]
}

#[test]
fn ids_round_trip_and_unknown_ids_are_refused() {
    let mut known = 0;
    for id in 0..=255u8 {
        if let Some(s) = Signal::from_id(id) {
            assert_eq!(s.id(), id);
            known += 1;
        }
    }
    assert_eq!(known, 4 * MAX_JOINTS + 5);
    for id in [0x40, 0x81, 0xd0, 0xff, MAX_JOINTS as u8] {
        assert_eq!(Signal::from_id(id), None, "{id:#x}");
    }
}

#[test]
fn bad_requests_are_refused_naming_what_and_where() {
    let mut r = recorder();
    assert_eq!(
        r.arm(&setup(&[0x00, 0x21, 0x45], 1, Trigger::Now, 0)),
        Err(RecorderError::BadSignal { index: 2, id: 0x45 })
    );
    assert_eq!(
        r.arm(&setup(&[], 1, Trigger::Now, 0)),
        Err(RecorderError::SignalCount { count: 0 })
    );
    let mut nine = setup(&[0x80; 8], 1, Trigger::Now, 0);
    nine.count = 9;
    assert_eq!(r.arm(&nine), Err(RecorderError::SignalCount { count: 9 }));
    assert_eq!(
        r.arm(&setup(&[0x80], 0, Trigger::Now, 0)),
        Err(RecorderError::Decimation)
    );
    let level = Trigger::Level {
        signal: 1,
        level: 0,
        rising: true,
    };
    assert_eq!(
        r.arm(&setup(&[0x80], 1, level, 0)),
        Err(RecorderError::TriggerSignal { index: 1 })
    );
    // Eight 16-bit signals: 90 samples in the ring; at most 89 before the trigger.
    let fe = [0x20, 0x21, 0x22, 0x23, 0x30, 0x31, 0x32, 0xc0];
    assert_eq!(
        r.arm(&setup(&fe, 1, Trigger::Now, 90)),
        Err(RecorderError::PreTrigger {
            pre: 90,
            capacity: 90
        })
    );
    assert_eq!(r.capture().phase, Phase::Off);
    assert!(r.arm(&setup(&fe, 1, Trigger::Now, 89)).is_ok());
}

#[test]
fn ring_holds_the_stated_samples() {
    let mut r = recorder();
    r.arm(&setup(
        &[0x20, 0x21, 0x22, 0x23, 0x30, 0x31, 0x32, 0xc0],
        1,
        Trigger::Now,
        0,
    ))
    .unwrap();
    assert_eq!(RING_BYTES / 16, 90);
    for v in 0..200 {
        r.sample(&[v; MAX_SIGNALS]);
    }
    assert_eq!(
        r.capture(),
        Capture {
            phase: Phase::Done,
            samples: 90,
            pre: 0,
            width: 16
        }
    );
    r.arm(&setup(
        &[0x00, 0x01, 0x02, 0x03, 0x10, 0x11, 0x80, 0xb0],
        1,
        Trigger::Now,
        0,
    ))
    .unwrap();
    assert_eq!(r.capture().width, 32);
    for v in 0..200 {
        r.sample(&[v; MAX_SIGNALS]);
    }
    assert_eq!(r.capture().samples, 45);
    let s = samples(&r);
    assert_eq!(s[0], vec![0; 8]);
    assert_eq!(s[44], vec![44; 8]);
}

#[test]
fn now_with_decimation_keeps_every_nth() {
    let mut r = recorder();
    // 4 + 2 + 4 bytes a sample: 144 samples.
    r.arm(&setup(&[0x00, 0x21, 0x80], 3, Trigger::Now, 0))
        .unwrap();
    assert!(r.wants(false) && !r.wants(true));
    for v in 0..3 * 144 + 10 {
        r.sample(&values(v));
    }
    assert_eq!(r.capture().phase, Phase::Done);
    assert!(!r.wants(false));
    let s = samples(&r);
    assert_eq!(s.len(), 144);
    for (i, row) in s.iter().enumerate() {
        let v = 3 * i as i32;
        assert_eq!(row, &vec![v, -v, 2 * v], "sample {i}");
    }
}

#[test]
fn a_level_crossing_keeps_the_pre_trigger_samples() {
    let mut r = recorder();
    let level = Trigger::Level {
        signal: 2,
        level: 1000,
        rising: true,
    };
    r.arm(&setup(&[0x00, 0x21, 0x80], 1, level, 50)).unwrap();
    // Signal 2 is 2v: it first reaches 1000 at v = 500, long after the ring wrapped.
    for v in 0..2000 {
        r.sample(&values(v));
    }
    let c = r.capture();
    assert_eq!((c.phase, c.samples, c.pre), (Phase::Done, 144, 50));
    let s = samples(&r);
    assert_eq!(s[50][2], 1000);
    assert_eq!(s[49][2], 998);
    assert_eq!(s[0][0], 450);
    assert_eq!(s[143][0], 450 + 143);
}

#[test]
fn a_falling_level_is_not_a_rising_one() {
    let mut r = recorder();
    let level = Trigger::Level {
        signal: 0,
        level: 0,
        rising: false,
    };
    r.arm(&setup(&[0x80], 1, level, 5)).unwrap();
    // Starting below the level and rising through it is no downward crossing.
    for v in -10..10 {
        r.sample(&[v; MAX_SIGNALS]);
    }
    assert_eq!(r.capture().phase, Phase::Armed);
    for v in (-10..10).rev() {
        r.sample(&[v; MAX_SIGNALS]);
    }
    assert_eq!(r.capture().phase, Phase::Triggered);
}

#[test]
fn an_alarm_between_decimated_samples_triggers_the_next() {
    let mut r = recorder();
    r.arm(&setup(&[0x20], 10, Trigger::Alarm, 30)).unwrap();
    // 960 samples of one 16-bit signal, one each 10 calls.
    for v in 0..12_000 {
        // An alarm raised at 705 and still there after: one event.
        r.observe(v >= 705, 7, v >= 705);
        r.sample(&[v; MAX_SIGNALS]);
    }
    let s = samples(&r);
    // Samples at 0, 10, 20, …: the trigger's is the first after the alarm (710).
    assert_eq!(s.len(), RING_BYTES / 2);
    assert_eq!(r.capture().pre, 30);
    assert_eq!(s[30], vec![710]);
    assert_eq!(s[0], vec![410]);
}

#[test]
fn a_line_trigger_waits_for_its_line() {
    let mut r = recorder();
    r.arm(&setup(&[0xb0], 1, Trigger::Line(42), 2)).unwrap();
    for line in 40..50 {
        r.observe(true, line, true);
        r.sample(&[line as i32; MAX_SIGNALS]);
        if line < 42 {
            assert_eq!(r.capture().phase, Phase::Armed);
        }
    }
    assert_eq!(r.capture().phase, Phase::Triggered);
    assert_eq!(r.capture().pre, 2);
}

#[test]
fn an_early_trigger_keeps_the_samples_there_are() {
    let mut r = recorder();
    // A job already open when armed is no job start.
    r.observe(true, 0, false);
    r.arm(&setup(&[0x80], 1, Trigger::JobStart, 100)).unwrap();
    r.observe(true, 0, false);
    r.observe(false, 0, false);
    r.sample(&[1; MAX_SIGNALS]);
    r.sample(&[2; MAX_SIGNALS]);
    r.observe(true, 0, false);
    for v in 3..1000 {
        r.sample(&[v; MAX_SIGNALS]);
    }
    let s = samples(&r);
    assert_eq!(r.capture().pre, 2);
    assert_eq!(s.len(), RING_BYTES / 4);
    assert_eq!(s[0], vec![1]);
    assert_eq!(s[2], vec![3]);
    assert_eq!(s[s.len() - 1], vec![s.len() as i32]);
}

#[test]
fn narrow_signals_saturate_and_nothing_is_read_before_the_end() {
    let mut r = recorder();
    r.arm(&setup(&[0x20, 0x30], 1, Trigger::Now, 0)).unwrap();
    r.sample(&[100_000, -100_000, 0, 0, 0, 0, 0, 0]);
    assert_eq!(r.read(0, &mut [0; 8]), 0);
    for _ in 1..RING_BYTES / 4 {
        r.sample(&[5; MAX_SIGNALS]);
    }
    assert_eq!(samples(&r)[0], vec![i16::MAX as i32, i16::MIN as i32]);
    r.disarm();
    assert_eq!(r.read(0, &mut [0; 8]), 0);
}
