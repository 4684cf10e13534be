//! The contract every model passes (after scikit-learn's `check_estimator`): shapes and names,
//! determinism, finite outputs, a clear error on the wrong inputs, constant targets, and for
//! models a file can hold, the same predictions after a save and a load.

use handcap::data::{Columns, Dataset};
use handcap::model::file::{ModelFile, StoredModel};
use handcap::model::msvr::PAPER_TABLE2;
use handcap::model::msvr::{Basis, MsvrParams};
use handcap::model::previous::{self, PreviousModel};
use handcap::model::ModelSpec;
use handcap::model::{ModelError, Predict};
use handcap::provenance::Provenance;
use handcap::synth::{self, SynthConfig};

use crate::common::tempdir;

/// A fitted model, and its stored form when it is a kind a model file holds.
type Fitted = (Box<dyn Predict>, Option<StoredModel>);

/// What a model can represent: a learner any smooth function (so a constant), a physics model
/// only the shapes its equations allow.
#[derive(Clone, Copy, PartialEq)]
pub enum Kind {
    Learner,
    Physics,
}

/// Fits with `fit` on `train` and checks the result, then checks the stored form's round trip
/// and a fit on constant targets.
pub fn check_regressor(
    fit: &dyn Fn(&Dataset) -> Result<Fitted, String>,
    kind: Kind,
    train: &Dataset,
) {
    let (model, stored) = fit(train).expect("fits the training data");
    check_fitted(model.as_ref(), train);

    if let Some(stored) = stored {
        let dir = tempdir();
        let path = dir.path().join("model.json");
        ModelFile::new(
            stored,
            None,
            None,
            None,
            None,
            Provenance::new(vec!["contract".into()], None),
        )
        .save(&path)
        .unwrap();
        let loaded = ModelFile::load(&path).unwrap().model;
        let loaded = loaded.predictor();
        assert_eq!(
            loaded.predict(&train.inputs).unwrap(),
            model.predict(&train.inputs).unwrap(),
            "a saved and loaded model predicts other values"
        );
    }

    // Constant targets (a stuck sensor, an output that never moved): the fit fails with an
    // error or gives finite predictions, a learner's the constant itself; never a panic or a NaN.
    let mut constant = train.clone();
    let width = constant.outputs.width();
    for (k, v) in constant.outputs.values.iter_mut().enumerate() {
        *v = 1.5 + (k % width) as f64;
    }
    let flat = fit(&constant);
    assert!(
        kind == Kind::Physics || flat.is_ok(),
        "a learner fails on constant targets: {:?}",
        flat.as_ref().err()
    );
    if let Ok((flat, _)) = flat {
        let pred = flat.predict(&constant.inputs).unwrap();
        for (k, v) in pred.values.iter().enumerate() {
            let want = 1.5 + (k % width) as f64;
            assert!(v.is_finite(), "constant target {want}, predicted {v}");
            if kind == Kind::Learner {
                assert!(
                    (v - want).abs() < 1e-6,
                    "constant target {want}, predicted {v}"
                );
            }
        }
    }
}

/// Checks a fitted model against the dataset it was fitted on.
fn check_fitted(model: &dyn Predict, train: &Dataset) {
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
        weights: None,
    }
}

#[test]
fn previous_model_passes_the_contract_in_both_variants() {
    let train = training_data();
    let default = PreviousModel::with_defaults();
    check_fitted(&default, &train);
    check_regressor(
        &|data| {
            let (calibrated, _) =
                previous::calibrate(data, &default.params).map_err(|e| e.to_string())?;
            Ok((Box::new(calibrated), None))
        },
        Kind::Physics,
        &train,
    );
}

#[test]
fn msvr_passes_the_contract() {
    let train = training_data();
    let params = MsvrParams::default()
        .with_hyper(PAPER_TABLE2)
        .check()
        .unwrap();
    check_regressor(
        &|data| {
            let model = params.fit(data).map_err(|e| e.to_string())?;
            Ok((Box::new(model.clone()), Some(StoredModel::Msvr(model))))
        },
        Kind::Learner,
        &train,
    );
}

#[test]
fn reduced_basis_msvr_passes_the_contract() {
    let train = training_data();
    let spec = ModelSpec::Msvr(MsvrParams::default().with_hyper(PAPER_TABLE2).basis(
        Basis::Reduced {
            centres: 40,
            seed: 5,
        },
    ));
    check_regressor(
        &|data| {
            let stored = spec.fit(data).map_err(|e| e.to_string())?;
            let StoredModel::Msvr(model) = &stored;
            Ok((Box::new(model.clone()), Some(stored)))
        },
        Kind::Learner,
        &train,
    );
}
