"""handcap from Python: multi-output SVR (one shared epsilon-tube for every output) whose
hyper-parameters an ant colony chooses, as a scikit-learn estimator over handcap's Rust core.

    import handcap
    model = handcap.MSVRRegressor(random_state=0).fit(X, Y)   # C, epsilon, sigma searched
    model.predict(X_new)
    model.save("model.json")          # `handcap predict model.json ...` reads it
    m = handcap.load("model.json")    # any `handcap model` file, with or without input history
    m.predict(X, time=t, groups=g)    # history models need each row's time (and group)
    inputs, achieved, error, reached = m.inverse(targets)

Each model family is an estimator of its own: MSVRRegressor (the paper's) and
KernelRidgeRegressor (`handcap model --model krr`); MSVRRegressor(model="auto") chooses between
them by the folds, as `handcap model` does by default.
"""

from ._core import Model, MIN_FIT_ROWS
from ._estimator import KernelRidgeRegressor, MSVRRegressor


def load(path):
    """Reads a model file written by `handcap model` or `save`; returns a `Model`."""
    return Model.load(str(path))


__all__ = ["MSVRRegressor", "KernelRidgeRegressor", "Model", "load", "MIN_FIT_ROWS"]
__version__ = "0.1.0"
