//! The contract every model passes (after scikit-learn's `check_estimator`): shapes and names,
//! determinism, finite outputs, a clear error on the wrong inputs.

use handcap::data::{Columns, Dataset};
use handcap::model::msvr::MsvrParams;
use handcap::model::previous::{self, PreviousModel};
use handcap::model::{ModelError, Predict};
use handcap::search::aco_paper::PAPER_TABLE2;
use handcap::synth::{self, SynthConfig};

/// Checks a fitted model against the dataset it was fitted on.
pub fn check_regressor(model: &dyn Predict, train: &Dataset) {
    assert_eq!(model.inputs(), train.inputs.names.as_slice());
    assert_eq!(model.outputs(), train.outputs.names.as_slice());

    let pred = model
        .predict(&train.inputs)
        .expect("predicts its own inputs");
    assert_eq!(pred.names, train.outputs.names);
    assert_eq!(pred.rows(), train.rows());
    assert!(
        pred.values.iter().all(|v| v.is_finite()),
        "non-finite prediction"
    );
    assert_eq!(
        model.predict(&train.inputs).unwrap(),
        pred,
        "not deterministic"
    );

    // Row by row agrees with the batch.
    let mut out = vec![0.0; model.outputs().len()];
    model.predict_row(train.inputs.row(0), &mut out);
    assert_eq!(out.as_slice(), pred.row(0));

    // Far outside the training range: still finite.
    let far = Columns::new(train.inputs.names.clone(), vec![1e6; train.inputs.width()]);
    assert!(model
        .predict(&far)
        .unwrap()
        .values
        .iter()
        .all(|v| v.is_finite()));

    // Wrong width or order of inputs: a clear error, not a panic or a silent mismatch.
    let mut names = train.inputs.names.clone();
    names.reverse();
    let swapped = Columns::new(names, train.inputs.values.clone());
    let err = model.predict(&swapped).unwrap_err();
    assert!(matches!(err, ModelError::InputMismatch { .. }));
    assert!(err.to_string().contains(&train.inputs.names[0]), "{err}");
    let narrow = Columns::new(
        train.inputs.names[..1].to_vec(),
        train.inputs.column(0).collect(),
    );
    assert!(matches!(
        model.predict(&narrow),
        Err(ModelError::InputMismatch { .. })
    ));
}

fn training_data() -> Dataset {
    let rec = synth::record(&SynthConfig::default()).unwrap().remove(0);
    Dataset {
        source: "train.csv".into(),
        inputs: rec.pressures,
        outputs: rec.tips,
    }
}

#[test]
fn previous_model_passes_the_contract_in_both_variants() {
    let train = training_data();
    let default = PreviousModel::with_defaults();
    check_regressor(&default, &train);
    let (calibrated, _) = previous::calibrate(&train, &default.params).unwrap();
    check_regressor(&calibrated, &train);
}

#[test]
fn msvr_passes_the_contract() {
    let train = training_data();
    let model = MsvrParams::default()
        .with_hyper(PAPER_TABLE2)
        .check()
        .unwrap()
        .fit(&train)
        .unwrap();
    check_regressor(&model, &train);
}
