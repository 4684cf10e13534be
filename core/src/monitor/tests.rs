//! The monitor against made-up rows with known changes.

use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// |N(0, 1)| errors, whose 0.9 quantile is 1.645.
fn errors(rng: &mut ChaCha8Rng, n: usize, scale: f64) -> Vec<f64> {
    (0..n)
        .map(|_| {
            let (u, v): (f64, f64) = (rng.random(), rng.random());
            scale * ((-2.0 * (1.0 - u).ln()).sqrt() * (std::f64::consts::TAU * v).cos()).abs()
        })
        .collect()
}

/// The one alarm `watched` raised, a camera's.
fn the_one_camera_alarm(watched: &Monitored) -> &Alarm {
    assert_eq!(watched.alarms.len(), 1, "{:?}", watched.alarms);
    let alarm = &watched.alarms[0];
    assert_eq!(alarm.channel, Channel::Camera);
    alarm
}

#[test]
fn the_band_holds_its_level_through_a_change_and_widens_after_it() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    // 20 000 rows as calibrated, then 20 000 twice as large.
    let mut e = errors(&mut rng, 20_000, 1.0);
    e.extend(errors(&mut rng, 20_000, 2.0));
    let times: Vec<f64> = (0..e.len()).map(|k| k as f64 / 30.0).collect();
    let errors = Series {
        times: &times,
        values: &e,
    };
    let watched = watch(errors, None, &[], None, 1.645, &Settings::default());
    assert!(
        (watched.coverage - 0.9).abs() < 0.005,
        "{}",
        watched.coverage
    );
    let late = &watched.rows[35_000..];
    let held = late.iter().filter(|r| r.covered).count() as f64 / late.len() as f64;
    assert!((held - 0.9).abs() < 0.02, "after the change: {held}");
    let band = late.iter().map(|r| r.band).sum::<f64>() / late.len() as f64;
    assert!(
        (band - 3.29).abs() < 0.25,
        "the band found the new quantile: {band}"
    );
    // The finger changed at 666.7 s: one model alarm, soon after, dated near it.
    let model: Vec<&Alarm> = watched
        .alarms
        .iter()
        .filter(|a| a.channel == Channel::Finger)
        .collect();
    assert!(!model.is_empty());
    assert_eq!(model.len(), 1);
    assert!(
        model[0].time_s > 666.6 && model[0].time_s < 730.0,
        "{:?}",
        model[0]
    );
    assert!((model[0].change_s - 666.7).abs() < 30.0, "{:?}", model[0]);
}

/// After an abrupt change (the errors three times as large from one row on), the band
/// holds at least 80 % of the next 60 rows (2 s at 30 fps) on average: its quick trackers
/// take over within a few rows. A single tracker of the middle step (the band before them)
/// held 74 % of the same kind of rows (a replica in Python, 50 sessions).
#[test]
fn after_an_abrupt_change_the_band_holds_most_of_the_next_two_seconds() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let sessions = 50;
    let mut held = 0.0;
    for _ in 0..sessions {
        let mut band = Band::new(1.645, 0.9, Settings::default().gain);
        for e in errors(&mut rng, 3000, 1.0) {
            band.update(e);
        }
        let after = errors(&mut rng, 60, 3.0);
        held += after.iter().filter(|&&e| band.update(e)).count() as f64 / 60.0;
    }
    let held = held / f64::from(sessions);
    assert!(
        held >= 0.8,
        "held {held:.3} of the 60 rows after the change"
    );
}

/// The reference is exactly the 114th of the baseline's 120 looks (one a second; scipy's
/// `binom.ppf(0.95, 120, 0.9) + 1`), at most the cap; a baseline of 28 looks, too few for
/// the bound, gives its plain 0.9 quantile; a bound that is +∞ (refused rows) does too.
#[test]
fn the_reference_is_the_binomial_order_statistic_of_the_baselines_looks() {
    let watched = |values: &[f64], cap: f64| {
        let mut w = Watcher::new(0.9, cap, 0.1, 10.0);
        for (k, &v) in values.iter().enumerate() {
            w.take(k as f64, v, values.len() as f64, 1.0);
        }
        w.decide().0
    };
    // 1, 2, …, 120 in a scrambled order (49 is prime to 120).
    let looks: Vec<f64> = (0..120).map(|k| f64::from((k * 49) % 120 + 1)).collect();
    assert_eq!(watched(&looks, f64::INFINITY), Some(114.0));
    assert_eq!(watched(&looks, 100.0), Some(100.0));
    let few: Vec<f64> = (1..=28).map(f64::from).collect();
    // Nearest rank: position round(27 × 0.9) = 24 of 0..27.
    assert_eq!(watched(&few, f64::INFINITY), Some(25.0));
    let mut refused = looks.clone();
    for v in refused.iter_mut().filter(|v| **v > 112.0) {
        *v = f64::INFINITY;
    }
    assert_eq!(watched(&refused, f64::INFINITY), Some(108.0));
}

/// A band of radius 0 fed errors of 0, or fed a value that is not a number, stays a number.
#[test]
fn the_band_stays_a_number_on_zero_and_non_finite_errors() {
    let mut band = Band::new(0.0, 0.9, Settings::default().gain);
    for _ in 0..100 {
        assert!(band.update(0.0));
    }
    assert!(band.radius().is_finite());
    let mut band = Band::new(1.0, 0.9, Settings::default().gain);
    assert!(!band.update(f64::NAN));
    assert!(!band.update(f64::INFINITY));
    assert!(band.update(0.5));
    assert!(band.radius().is_finite() && band.radius() > 0.0);
}

/// A baseline is a sample: its 0.9 quantile falls below the errors' own in about half the
/// sessions, and the rest of such a session then misses more often than p₀. The reference is
/// a 95 % upper bound of it over the baseline's looks: below the errors' quantile (1.645) in
/// 2-8 % of 400 sessions, where the plain quantile of the same baselines is below it in more
/// than a third.
#[test]
fn the_reference_bounds_the_baselines_quantile_from_above_in_nineteen_sessions_of_twenty() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let settings = Settings::default();
    let (sessions, rows) = (400, 130 * 30);
    let times: Vec<f64> = (0..rows).map(|k| k as f64 / 30.0).collect();
    let (mut below, mut plain_below) = (0, 0);
    for _ in 0..sessions {
        let e = errors(&mut rng, rows, 1.0);
        let watched = watch(
            Series {
                times: &times,
                values: &e,
            },
            None,
            &[],
            None,
            100.0,
            &settings,
        );
        below += usize::from(watched.model_reference < 1.645);
        let mut baseline = e[..120 * 30].to_vec();
        let [plain] = crate::stats::quantiles(&mut baseline, [0.9]).unwrap();
        plain_below += usize::from(plain < 1.645);
    }
    let share = below as f64 / sessions as f64;
    assert!(
        (0.02..=0.08).contains(&share),
        "below in {below} of {sessions}"
    );
    // The plain quantile of the same baselines, for scale: below in about half.
    assert!(plain_below > sessions / 3, "{plain_below} of {sessions}");
}

/// 550 hours of looks with nothing changed, a fresh CUSUM after each false alarm: they
/// come no more often than asked (here once per 2 h at most, on average).
#[test]
fn false_alarms_are_no_more_frequent_than_stated() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let settings = Settings {
        false_alarm_hours: 2.0,
        ..Settings::default()
    };
    let looks = 2_000_000;
    let mut cusum = Cusum::new(0.1, settings.threshold());
    let mut alarms = 0;
    for _ in 0..looks {
        if cusum.look(rng.random::<f64>() < 0.1).is_some() {
            alarms += 1;
            cusum = Cusum::new(0.1, settings.threshold());
        }
    }
    let per_hour = f64::from(alarms) / (f64::from(looks) / 3600.0);
    assert!(per_hour <= 0.5, "{alarms} alarms in {} h", looks / 3600);
}

#[test]
fn a_camera_that_moves_raises_the_geometry_alarm_not_the_models() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let n = 30 * 300;
    let e = errors(&mut rng, n, 1.0);
    let mut r = errors(&mut rng, n, 0.2);
    // At 200 s the residuals grow fourfold.
    for v in &mut r[30 * 200..] {
        *v *= 4.0;
    }
    let times: Vec<f64> = (0..n).map(|k| k as f64 / 30.0).collect();
    let (errors, geometry) = (
        Series {
            times: &times,
            values: &e,
        },
        Series {
            times: &times,
            values: &r,
        },
    );
    let watched = watch(
        errors,
        Some(geometry),
        &[],
        None,
        1.645,
        &Settings::default(),
    );
    let alarm = the_one_camera_alarm(&watched);
    assert!(alarm.time_s >= 200.0 && alarm.time_s < 230.0, "{alarm:?}");
    assert!((alarm.change_s - 200.0).abs() < 10.0, "{alarm:?}");
}

/// A camera that moves shifts the tips too: the finger alarm that follows says so.
#[test]
fn a_finger_alarm_after_a_camera_alarm_points_at_the_camera() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let n = 30 * 300;
    let mut e = errors(&mut rng, n, 1.0);
    let mut r = errors(&mut rng, n, 0.2);
    for k in 30 * 200..n {
        (e[k], r[k]) = (e[k] * 3.0, r[k] * 4.0);
    }
    let times: Vec<f64> = (0..n).map(|k| k as f64 / 30.0).collect();
    let series = |values| Series {
        times: &times,
        values,
    };
    let watched = watch(
        series(&e),
        Some(series(&r)),
        &[],
        None,
        1.645,
        &Settings::default(),
    );
    let finger = watched
        .alarms
        .iter()
        .find(|a| a.channel == Channel::Finger)
        .unwrap();
    assert_eq!(finger.advice, FINGER_AFTER_CAMERA);
    let alone = watch(series(&e), None, &[], None, 1.645, &Settings::default());
    assert_eq!(alone.alarms[0].advice, Channel::Finger.advice());
}

/// Rows the triangulation refused because the views disagree are geometry misses (+∞):
/// a camera knocked so far that no row passes still raises the alarm, on the model's rows
/// around it.
#[test]
fn rows_refused_as_inconsistent_are_camera_misses() {
    let times: Vec<f64> = (0..30 * 300).map(|k| k as f64 / 30.0).collect();
    let r: Vec<f64> = times
        .iter()
        .map(|&t| {
            if t < 200.0 {
                0.1 + 0.05 * (t * 7.0).sin()
            } else {
                f64::INFINITY
            }
        })
        .collect();
    // The model's rows stop where the tips do: the refused rows have none.
    let n = 30 * 200;
    let e = vec![0.5; n];
    let errors = Series {
        times: &times[..n],
        values: &e,
    };
    let geometry = Series {
        times: &times,
        values: &r,
    };
    let watched = watch(errors, Some(geometry), &[], None, 1.0, &Settings::default());
    let alarm = the_one_camera_alarm(&watched);
    assert!(alarm.time_s >= 200.0 && alarm.time_s < 215.0, "{alarm:?}");
    assert_eq!(alarm.row, n - 1);
}

/// A finger moving over a disk of 8 mm, the model biased by up to 0.3 mm depending on
/// where, 0.05 mm of noise; from `change_s` its displacement is `scale` times the model's.
/// The response test alone (the rows' outputs, no errors): its alarms.
fn responding(seconds: f64, change_s: f64, scale: f64) -> Vec<Alarm> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut monitor = Monitor::new(1.0, &Settings::default()).with_rest(vec![0.0; 3]);
    let mut alarms = Vec::new();
    for k in 0..(seconds * 30.0) as usize {
        let t = k as f64 / 30.0;
        let d = [
            8.0 * (0.31 * t).sin() * (0.17 * t).cos(),
            8.0 * (0.23 * t).sin(),
            0.5 * (0.11 * t).sin(),
        ];
        let bias = 0.3 * (d[0] / 2.0).sin();
        let s = if t >= change_s { scale } else { 1.0 };
        let got: Vec<f64> = (0..3)
            .map(|i| s * d[i] + bias * [0.6, 0.8, 0.0][i] + 0.05 * (rng.random::<f64>() - 0.5))
            .collect();
        alarms.extend(monitor.outputs(t, &d, &got));
    }
    alarms
}

/// A response 15 % larger or smaller raises the finger alarm within 30 s, saying which;
/// two hours of the same finger with its model's bias wandering over the disk raise none.
#[test]
fn a_finger_responding_more_or_less_than_modelled_is_told_within_half_a_minute() {
    for (scale, advice) in [(1.15, FURTHER), (0.85, LESS)] {
        let alarms = responding(900.0, 600.0, scale);
        assert_eq!(alarms.len(), 1, "{alarms:?}");
        let alarm = &alarms[0];
        assert_eq!(alarm.channel, Channel::Finger);
        assert_eq!(alarm.advice, advice, "{alarm:?}");
        assert!(alarm.time_s > 600.0 && alarm.time_s < 630.0, "{alarm:?}");
        assert!((alarm.change_s - 600.0).abs() < 30.0, "{alarm:?}");
    }
    let calm = responding(7200.0, f64::INFINITY, 1.0);
    assert!(calm.is_empty(), "{calm:?}");
    // A change in the baseline's last seconds: the statistic is never 0 after the baseline,
    // and the change is dated at its first look after it (it was −∞).
    let at_once = responding(300.0, 110.0, 1.3);
    assert_eq!(at_once.len(), 1, "{at_once:?}");
    let change = at_once[0].change_s;
    assert!((120.0..122.0).contains(&change), "{:?}", at_once[0]);
}

#[test]
fn settings_out_of_range_are_named() {
    let bad = Settings {
        level: 1.0,
        ..Settings::default()
    };
    assert!(bad.check().unwrap_err().contains("level"));
    assert!(Settings::default().check().is_ok());
}

/// A camera that pans moves its beads along their epipolar lines: the residual stays calm,
/// the still scene in its view moves. The scene channel names that camera, and a drift of
/// the scene below [`SCENE_FLOOR_PX`] (a camera's view a few tenths of a pixel off after a
/// calm, very steady baseline) raises nothing.
#[test]
fn a_camera_whose_view_of_the_still_scene_moved_is_named() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let n = 30 * 300;
    let times: Vec<f64> = (0..n).map(|k| k as f64 / 30.0).collect();
    let e = errors(&mut rng, n, 1.0);
    let r = errors(&mut rng, n, 0.1);
    let steady = errors(&mut rng, n, 0.01);
    let drifting: Vec<f64> = steady
        .iter()
        .zip(&times)
        .map(|(v, &t)| v + if t >= 200.0 { 0.3 } else { 0.0 })
        .collect();
    let mut moved = errors(&mut rng, n, 0.05);
    for v in &mut moved[30 * 200..] {
        *v += 8.0;
    }
    let series = |values| Series {
        times: &times,
        values,
    };
    let scene = [("left", series(&drifting)), ("right", series(&moved))];
    let watched = watch(
        series(&e),
        Some(series(&r)),
        &scene,
        None,
        1.645,
        &Settings::default(),
    );
    let alarm = the_one_camera_alarm(&watched);
    assert_eq!(alarm.camera.as_deref(), Some("right"));
    assert!(alarm.time_s >= 200.0 && alarm.time_s < 215.0, "{alarm:?}");
    assert!((alarm.change_s - 200.0).abs() <= 2.0, "{alarm:?}");
    assert!(alarm.to_string().contains("camera (right)"), "{alarm}");
    // The steady camera's reference is the floor, not its baseline's 0.02 px.
    assert_eq!(
        watched.scene_references_px[0],
        ("left".into(), Some(SCENE_FLOOR_PX))
    );
    // A camera whose scene was first told after the baseline (none in it) is watched against
    // the floor.
    let late = 30 * 150;
    let scene = [(
        "right",
        Series {
            times: &times[late..],
            values: &moved[late..],
        },
    )];
    let watched = watch(series(&e), None, &scene, None, 1.645, &Settings::default());
    let reference = &watched.scene_references_px[0];
    assert_eq!(reference, &("right".into(), Some(SCENE_FLOOR_PX)));
    let alarm = the_one_camera_alarm(&watched);
    assert!(alarm.time_s >= 200.0 && alarm.time_s < 215.0, "{alarm:?}");
}
