use super::*;

fn history(memory: Memory) -> History {
    History {
        time: "t".into(),
        group: Some("g".into()),
        inputs: vec!["u".into()],
        memory,
    }
}

fn one_input(values: &[f64]) -> Columns {
    Columns::new(vec!["u".into()], values.to_vec())
}

#[test]
fn ema_by_hand_per_group_with_irregular_steps() {
    let h = history(Memory::Ema { tau: vec![1.0] });
    // Group 0: a step from 0 to 1 seen at t = 0, 1, 3; group 1 interleaved, held at 5.
    let series = Series {
        time: vec![0.0, 0.0, 1.0, 1.0, 3.0],
        group: Some(vec![0.0, 1.0, 0.0, 1.0, 0.0]),
    };
    let f = h
        .features(&one_input(&[0.0, 5.0, 1.0, 5.0, 1.0]), &series)
        .unwrap();
    assert_eq!(f.names, ["u", "u@ema1"]);
    let e1 = 1.0 - (-1.0f64).exp();
    let e3 = e1 + (1.0 - e1) * (1.0 - (-2.0f64).exp());
    let expected = [0.0, 0.0, 5.0, 5.0, 1.0, e1, 5.0, 5.0, 1.0, e3];
    for (v, e) in f.values.iter().zip(expected) {
        assert!((v - e).abs() < 1e-15, "{:?}", f.values);
    }
}

#[test]
fn lags_start_at_the_first_row() {
    let h = history(Memory::Lags { rows: 2 });
    let series = Series {
        time: vec![0.0, 1.0, 2.0, 3.0],
        group: None,
    };
    let h = History { group: None, ..h };
    let f = h
        .features(&one_input(&[1.0, 2.0, 3.0, 4.0]), &series)
        .unwrap();
    assert_eq!(f.names, ["u", "u@lag1", "u@lag2"]);
    assert_eq!(
        f.values,
        [1.0, 1.0, 1.0, 2.0, 1.0, 1.0, 3.0, 2.0, 1.0, 4.0, 3.0, 2.0]
    );
}

#[test]
fn time_must_increase_within_a_group() {
    let series = Series {
        time: vec![0.0, 1.0, 1.0],
        group: Some(vec![3.0, 3.0, 3.0]),
    };
    let e = series.check().unwrap_err();
    assert_eq!(e.row(), Some(2));
    assert_eq!(
        e.to_string(),
        "time 1 repeats the previous row's 1 in group 3: rows must be in time order within each group"
    );
    // Another group may restart the clock.
    let ok = Series {
        time: vec![0.0, 1.0, 0.0],
        group: Some(vec![3.0, 3.0, 4.0]),
    };
    assert_eq!(ok.check().unwrap().len(), 2);
}

#[test]
fn short_groups_are_refused() {
    let h = history(Memory::Lags { rows: 3 });
    let series = Series {
        time: vec![0.0, 1.0, 2.0, 0.0, 1.0, 2.0, 3.0],
        group: Some(vec![1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0]),
    };
    let e = h
        .features(&one_input(&[0.0, 1.0, 2.0, 0.0, 1.0, 2.0, 3.0]), &series)
        .unwrap_err();
    assert_eq!(
        e.to_string(),
        "group 1: 3 rows, but lags:3 needs at least 4 per group"
    );
}

#[test]
fn time_constants_follow_the_sampling() {
    let series = Series {
        time: (0..200).map(|i| 0.05 * i as f64).collect(),
        group: None,
    };
    // 0.5 × 0.05 = 0.025, then × 4; each ladder starting × 2 later; nothing longer than
    // half the 9.95 s span.
    assert_eq!(
        series.time_constant_ladders().unwrap(),
        [
            vec![0.025, 0.1, 0.4],
            vec![0.05, 0.2, 0.8],
            vec![0.1, 0.4, 1.6],
            vec![0.2, 0.8, 3.2],
            vec![0.4, 1.6]
        ]
    );
    let short = Series {
        time: vec![0.0, 1.0, 2.0],
        group: None,
    };
    // A 2 s span: constants up to 1 s.
    assert_eq!(
        short.time_constant_ladders().unwrap(),
        [vec![0.5], vec![1.0]]
    );
}

#[test]
fn choices_parse() {
    assert_eq!(
        "ema:0.25,1,4".parse::<HistoryChoice>(),
        Ok(HistoryChoice::Ema(vec![0.25, 1.0, 4.0]))
    );
    assert_eq!("lags:3".parse(), Ok(HistoryChoice::Lags(3)));
    for bad in ["ema:", "ema:-1", "lags:0", "lag:2", "ema:1,x"] {
        assert!(bad.parse::<HistoryChoice>().is_err(), "{bad}");
    }
}

#[test]
fn features_of_a_file_run_through_its_flagged_rows() {
    // A frame without the tip (flagged, no outputs) still had its input: the lag after it is
    // that input, and the filter sees it, rather than bridging the gap. A flagged row that
    // has no input is passed over. Groups are labels ("a", "b").
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("log.csv");
    std::fs::write(
        &path,
        "t,g,u,y,flag\n0,a,1,10,\n1,a,2,,gap\n2,a,3,30,\n3,a,,,gap\n4,a,5,50,\n0,b,7,70,\n1,b,8,80,\n",
    )
    .unwrap();
    let lags = History {
        group: Some("g".into()),
        ..history(Memory::Lags { rows: 1 })
    };
    let (inputs, f) = lags.read_features(&path).unwrap();
    assert_eq!(inputs.values, [1.0, 3.0, 5.0, 7.0, 8.0]);
    // Row t = 2 lags to the flagged 2, not to 1; t = 4 to 3 (the row without an input is
    // passed over); group b starts afresh.
    assert_eq!(f.values, [1.0, 1.0, 3.0, 2.0, 5.0, 3.0, 7.0, 7.0, 8.0, 7.0]);
    let ema = History {
        group: Some("g".into()),
        ..history(Memory::Ema { tau: vec![1.0] })
    };
    let (_, f) = ema.read_features(&path).unwrap();
    let gain = 1.0 - (-1.0f64).exp();
    // The filter at t = 1 (flagged) and t = 2.
    let at1 = 1.0 + gain * (2.0 - 1.0);
    let at2 = at1 + gain * (3.0 - at1);
    assert!((f.values[3] - at2).abs() < 1e-12, "{:?}", f.values);
}

/// `auto` keeps a history only when it lowers the cross-validated error by more than 2 % and
/// by more than one standard error of the paired fold differences; a near-tie is the present
/// inputs'.
#[test]
fn history_is_kept_beyond_one_standard_error_and_two_percent() {
    let ema = history(Memory::Ema { tau: vec![1.0] });
    let decide_at = |history_fitness: f64, paired: Option<(f64, f64)>| {
        let params = MsvrParams::default();
        decide(
            vec![
                (None, 1.0, params),
                (Some(ema.clone()), history_fitness, params),
            ],
            Vec::new(),
            "history=auto",
            paired,
        )
    };
    let won = decide_at(0.9, Some((0.1, 0.03)));
    assert_eq!(won.used, Some(ema.clone()));
    assert!(won.reason.contains("more than one standard error"));
    let tie = decide_at(0.9, Some((0.1, 0.12)));
    assert_eq!(tie.used, None);
    assert!(
        tie.reason.contains("within one standard error"),
        "{}",
        tie.reason
    );
    let small = decide_at(0.99, Some((0.01, 0.001)));
    assert_eq!(small.used, None);
    assert!(small
        .reason
        .contains("does not lower the cross-validated error by 2 %"));
    // Without the folds' errors, the 2 % gain alone.
    assert_eq!(decide_at(0.9, None).used, Some(ema));
}
