use super::*;
use crate::data::Columns;

fn default_params() -> PreviousParams {
    PreviousParams::default()
}

#[test]
fn zero_pressure_is_the_origin() {
    let tip = default_params().tip([0.0; 3]);
    assert_eq!(tip, [0.0, 0.0, 0.0]);
}

#[test]
fn equal_pressures_contract_along_z_only() {
    let p = default_params();
    let mut last_z = 0.0;
    for kpa in [20.0, 100.0, 250.0] {
        let tip = p.tip([kpa; 3]);
        assert!(tip[0].abs() < 1e-12 && tip[1].abs() < 1e-12, "{tip:?}");
        assert!(tip[2] > last_z, "z must grow with pressure: {tip:?}");
        // Pure contraction: z is exactly L0 κ.
        assert!((tip[2] - p.length_mm * p.contraction(kpa)).abs() < 1e-12);
        last_z = tip[2];
    }
}

#[test]
fn one_muscle_bends_the_tip_towards_its_own_side_in_the_direction_of_eq_2() {
    let p = default_params();
    for muscle in 0..3 {
        let mut pressures = [0.0; 3];
        pressures[muscle] = 150.0;
        let tip = p.tip(pressures);
        let [mx, my] = p.muscle_xy_mm[muscle];
        // Towards the muscle: the tip's lateral move points to the muscle's side.
        assert!(tip[0] * mx + tip[1] * my > 0.0, "muscle {muscle}: {tip:?}");
        // Its direction is eq. 2's γ, written as the paper writes it.
        let Bend { normal, gamma, .. } = p.bend(p.muscle_lengths(pressures));
        let [a, b, _] = normal;
        let eq2 = if b >= 0.0 {
            (a / a.hypot(b)).acos()
        } else {
            -(a / a.hypot(b)).acos()
        };
        assert!((gamma - eq2).abs() < 1e-9, "{gamma} vs {eq2}");
        assert!((tip[1].atan2(tip[0]) - gamma).abs() < 1e-9);
        // It contracts as it bends.
        assert!(tip[2] > 0.0);
    }
    // Muscle 3 (at +x) pushes the tip to +x, muscle 1 to −x, muscle 2 (at +y) to +y.
    assert!(p.tip([0.0, 0.0, 150.0])[0] > 1.0);
    assert!(p.tip([150.0, 0.0, 0.0])[0] < -1.0);
    assert!(p.tip([0.0, 150.0, 0.0])[1] > 1.0);
}

#[test]
fn b_zero_and_no_bend_are_handled_like_eq_2() {
    let p = default_params();
    // Muscles 1 and 3 lengthen equally relative to 2 → the plane tilts along y only: b ≠ 0,
    // a = 0. Lengthening muscle 1 against 3 only tilts in x and y; a straight finger has
    // a = b = 0 and γ = 0 with no NaN anywhere.
    let straight = p.bend([50.0; 3]);
    assert_eq!(straight.theta, 0.0);
    assert_eq!(straight.gamma, 0.0);
    // A bend with b = 0 and a < 0: γ = π by eq. 2's first branch.
    let q = PreviousParams {
        muscle_xy_mm: [[-1.0, -1.0], [0.0, 1.0], [1.0, -1.0]],
        ..default_params()
    };
    let lengths = [49.0, 49.5, 50.0];
    let bend = q.bend(lengths);
    assert!(bend.normal[1].abs() < 1e-15, "{:?}", bend.normal);
    assert!(bend.normal[0] < 0.0);
    assert!((bend.gamma - PI).abs() < 1e-12);
}

#[test]
fn theta_to_zero_is_continuous() {
    let p = default_params();
    let straight = p.tip_from_lengths([49.0; 3]);
    assert_eq!(straight, [0.0, 0.0, 1.0]);
    // Shortening one muscle by δ moves the tip by O(δ) (about L̄ θ / 2 with θ ≈ 0.58 δ per
    // mm here), through the series branch (θ < 1e-8) and out of it, with no NaN and no jump.
    for delta in [1e-2, 1e-4, 1e-6, 1e-8, 1e-9, 1e-10, 1e-12, 1e-14, 0.0] {
        let tip = p.tip_from_lengths([49.0 - delta, 49.0, 49.0]);
        let moved = (0..3).map(|j| (tip[j] - straight[j]).abs()).sum::<f64>();
        assert!(moved <= 25.0 * delta + 1e-13, "δ = {delta}: {tip:?}");
    }
}

#[test]
fn contraction_is_zero_at_rest_monotone_and_bounded_by_the_free_muscle() {
    let p = default_params();
    assert_eq!(p.contraction(0.0), 0.0);
    let free = 1.0 - (1.0 / (3.0f64.sqrt() * p.braid_angle_deg.to_radians().cos()));
    let mut last = 0.0;
    for kpa in (10..=300).step_by(10) {
        let k = p.contraction(kpa as f64);
        assert!(k > last && k < free, "{kpa} kPa: {k}");
        last = k;
    }
    assert!(p.contraction(1e9) < free);
    // Below the threshold nothing moves.
    let q = PreviousParams {
        threshold_kpa: 30.0,
        ..default_params()
    };
    assert_eq!(q.contraction(29.0), 0.0);
    assert!(q.contraction(31.0) > 0.0);
}

#[test]
fn bad_constants_are_refused() {
    let bad = [
        PreviousParams {
            braid_angle_deg: 60.0,
            ..default_params()
        },
        PreviousParams {
            load_n: 0.0,
            ..default_params()
        },
        PreviousParams {
            arm_y: f64::NAN,
            ..default_params()
        },
        PreviousParams {
            muscle_xy_mm: [[1.25, -0.4], [0.0, 0.8], [-1.25, -0.4]],
            ..default_params()
        },
    ];
    for p in bad {
        assert!(matches!(p.check(), Err(PreviousError::Invalid(_))), "{p:?}");
    }
}

fn grid_dataset(params: &PreviousParams) -> Dataset {
    let steps: Vec<f64> = (0..=5).map(|k| 50.0 * k as f64).collect();
    let (mut x, mut y) = (Vec::new(), Vec::new());
    for &p1 in &steps {
        for &p2 in &steps {
            for &p3 in &steps {
                x.extend([p1, p2, p3]);
                y.extend(params.tip([p1, p2, p3]));
            }
        }
    }
    Dataset {
        source: "grid".into(),
        inputs: Columns::new(names(&HAND_INPUTS), x),
        outputs: Columns::new(names(&HAND_OUTPUTS), y),
        weights: None,
    }
}

#[test]
fn calibration_recovers_the_constants_that_generated_the_data() {
    let truth = PreviousParams {
        braid_angle_deg: 32.0,
        load_n: 30.0,
        threshold_kpa: 15.0,
        arm_x: 1.3,
        arm_y: 0.8,
        ..default_params()
    };
    let data = grid_dataset(&truth);
    let (model, cal) = calibrate(&data, &default_params()).unwrap();
    let got = &model.params;
    let rel = |a: f64, b: f64| ((a - b) / b).abs();
    assert!(cal.rms_mm < 1e-6, "{cal:?}");
    assert!(rel(got.braid_angle_deg, 32.0) < 1e-4, "{got:?}");
    assert!(rel(got.load_n, 30.0) < 1e-4, "{got:?}");
    assert!((got.threshold_kpa - 15.0).abs() < 1e-3, "{got:?}");
    assert!(
        rel(got.arm_x, 1.3) < 1e-4 && rel(got.arm_y, 0.8) < 1e-4,
        "{got:?}"
    );
    assert_eq!(model.variant, Variant::Calibrated);
    assert!(cal.converged);
}

#[test]
fn calibration_refuses_other_columns() {
    let mut data = grid_dataset(&default_params());
    data.outputs.names[0] = "u".into();
    assert!(matches!(
        calibrate(&data, &default_params()),
        Err(PreviousError::NotTheHand { .. })
    ));
}
