use super::*;

/// Open-loop data of `tf` under a PRBS input of ±1 c.u. held 10 periods, position
/// exact (no quantisation), 1 s at 10 kHz.
fn open_loop(tf: &TransferFunction) -> Record {
    let h = 1e-4;
    let mut p = tf.discretize(h);
    let u = prbs(10_000, 10, 0x0ace);
    let mut y = Vec::with_capacity(u.len());
    for &v in &u {
        y.push(p.output(0.0));
        p.step(v);
    }
    Record { h, u, y }
}

#[test]
fn the_prbs_is_binary_held_and_balanced() {
    let s = prbs(32_767 * 3, 3, 1);
    assert!(s.iter().all(|v| v.abs() == 1.0));
    assert!(s.chunks(3).all(|c| c.iter().all(|v| *v == c[0])));
    // A maximal-length sequence has one more +1 than −1 per period.
    let sum: f64 = s.iter().sum();
    assert_eq!(sum, 3.0);
}

#[test]
fn least_squares_recovers_an_exact_fit() {
    let rows: Vec<Vec<f64>> = (0..20)
        .map(|i| vec![1.0, i as f64, (i * i) as f64])
        .collect();
    let rhs: Vec<f64> = rows.iter().map(|r| 2.0 - 3.0 * r[1] + 0.5 * r[2]).collect();
    let x = lstsq(rows, rhs).unwrap();
    for (a, b) in x.iter().zip([2.0, -3.0, 0.5]) {
        assert!((a - b).abs() < 1e-10, "{x:?}");
    }
}

#[test]
fn an_integrating_plant_is_found_from_noise_free_data() {
    // The simulator's default plant at 1 µm per count: 0.3 mm/s per c.u., 20 ms lag.
    let tf = TransferFunction::new(&[0.3], &[0.02, 1.0, 0.0]).unwrap();
    let id = identify(&open_loop(&tf), &IdentOptions::default()).unwrap();
    assert!(id.fit_percent > 95.0, "{id:?}");
    for w in [1.0, 10.0, 50.0, 200.0] {
        let (a, b) = (id.plant.at(w), tf.at(w));
        let rel = (a - b).abs() / b.abs();
        assert!(rel < 0.02, "{w} rad/s: {rel}");
    }
}

#[test]
fn a_stable_plant_is_found_without_the_integrator() {
    // A lightly damped second-order plant: 2 mm/c.u., 30 rad/s, ζ = 0.2.
    let tf = TransferFunction::new(&[1800.0], &[1.0, 12.0, 900.0]).unwrap();
    let o = IdentOptions {
        integrating: false,
        ..IdentOptions::default()
    };
    let id = identify(&open_loop(&tf), &o).unwrap();
    for w in [1.0, 10.0, 30.0, 100.0] {
        let (a, b) = (id.plant.at(w), tf.at(w));
        let rel = (a - b).abs() / b.abs();
        assert!(rel < 0.03, "{w} rad/s: {rel} {id:?}");
    }
}

#[test]
fn bad_records_are_refused() {
    let o = IdentOptions::default();
    let short = Record {
        h: 1e-4,
        u: vec![1.0; 100],
        y: vec![0.0; 100],
    };
    assert!(matches!(
        identify(&short, &o),
        Err(IdentError::TooShort { .. })
    ));
    let mut r = Record {
        h: 1e-4,
        u: vec![1.0; 10_000],
        y: vec![0.0; 10_000],
    };
    assert_eq!(identify(&r, &o), Err(IdentError::NoExcitation));
    r.y[5] = f64::NAN;
    assert_eq!(identify(&r, &o), Err(IdentError::NotFinite));
    r.y.pop();
    assert_eq!(identify(&r, &o), Err(IdentError::Shape));
}
