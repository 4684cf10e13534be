"""The scikit-learn estimator over handcap's core."""

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.utils.validation import _check_sample_weight, check_is_fitted, validate_data

from . import _core

# The seed when random_state is None: handcap's default (every run is reproducible).
DEFAULT_SEED = 2020


class MSVRRegressor(RegressorMixin, BaseEstimator):
    """Multi-output support vector regression with one spherical epsilon-tube for all outputs.

    Hyper-parameters left None are chosen inside `fit` by a continuous ant colony (ACO_R) over a
    box derived from the data, scored by cross-validated MAE (on whole `groups` when given, else
    on folds the data call for: shuffled for a design, contiguous blocks for a time series).

    Parameters
    ----------
    C, epsilon, sigma : float or None
        Penalty, tube radius (output units) and RBF width (inputs scaled to [0, 1]); None: searched.
    model : {"msvr", "krr", "auto"}
        The paper's MSVR; kernel ridge ("krr": the squared loss and no tube, MSVR with epsilon 0,
        searching C and sigma; `loss` does not apply and epsilon stays None); or "auto", both
        searched on the same folds and the lower cross-validated error kept, as
        `handcap model --model auto`.
    search : {"aco-r", "none"}
        "none" requires C, epsilon and sigma.
    budget : int or None
        Candidates the search scores (default: from the rows, 400 up to 400 rows, 200 up to 700,
        120 above).
    loss : {"robust", "quadratic"}
        Beyond the tube: quadratic for 10 epsilon then linear ("robust"), or the paper's quadratic.
    basis : "auto", "exact" or int
        A kernel at every row ("exact"), a reduced basis of that many centres, or exact up to 2000
        rows and a grown reduced basis above ("auto").
    folds : int
        Cross-validation folds of the search and the intervals; fewer rows than 2 per fold get
        as many folds as they allow.
    history : str
        With `time` given to `fit`: "auto" (filtered copies of the inputs, kept when
        cross-validation says they help), "none", "ema:tau1,tau2,..." (seconds) or "lags:k".
    intervals : bool
        Conformal prediction intervals (`interval_radius`) come with every search: from its own
        held-out predictions at no cost, or with `groups`, from folds of consecutive runs (one
        more fit per fold: runs recorded one after another drift). True calibrates them also
        without a search (C, epsilon and sigma all given: one more fit per fold); False fits
        that case's model alone (one fit, what a control loop refitting online wants).
    random_state : int or None
        Seeds the search and its folds (None: handcap's default seed, 2020).
    tol, max_iter : solver controls.

    Attributes
    ----------
    C_, epsilon_, sigma_ : the hyper-parameters fitted with.
    support_vectors_ : (n_sv, n_features) the kernel's centres, in inputs scaled to [0, 1].
    dual_coef_ : (n_sv, n_outputs) their coefficients.
    intercept_ : (n_outputs,)
    n_iter_ : int, iterations of the final fit's solver.
    model_ : handcap.Model, the fitted model (save, inverse).
    family_ : str, "msvr" or "krr": the family fitted.
    search_ : dict or None, what the search did.
    """

    def __init__(self, C=None, epsilon=None, sigma=None, model="msvr", search="aco-r",
                 budget=None, loss="robust", basis="auto", folds=5, history="auto",
                 random_state=None, tol=1e-8, max_iter=500, intervals=False):
        self.C = C
        self.epsilon = epsilon
        self.sigma = sigma
        self.model = model
        self.search = search
        self.budget = budget
        self.loss = loss
        self.basis = basis
        self.folds = folds
        self.history = history
        self.random_state = random_state
        self.tol = tol
        self.max_iter = max_iter
        self.intervals = intervals

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.target_tags.multi_output = True
        tags.target_tags.single_output = True
        return tags

    def fit(self, X, y, groups=None, time=None, sample_weight=None):
        """Fits the model (searching the hyper-parameters left None). `groups`: one label per
        row; the search holds whole groups out together (runs, trials, ramps). `time`: each
        row's time in seconds, increasing within each group: the model may see its inputs'
        history (`history`), as `handcap model --time --group-by` does. `sample_weight`: each
        row's weight in the loss (C w L, as `handcap model --weight`): a row of weight k is
        fitted as k copies of it; the folds' scores and the intervals count every row once.
        Rows of weight 0 are left out (not with `time`, whose history needs every row)."""
        X, y = validate_data(self, X, y, multi_output=True, y_numeric=True, dtype=np.float64,
                             ensure_min_samples=_core.MIN_FIT_ROWS)
        weights = None
        if sample_weight is not None:
            weights = _check_sample_weight(sample_weight, X, dtype=np.float64,
                                           ensure_non_negative=True)
        if self.search not in ("aco-r", "none"):
            raise ValueError(f"search {self.search!r}: give 'aco-r' or 'none'")
        families = dict(_core.FAMILIES)
        if not (isinstance(self.model, str) and self.model in ["auto", *families]):
            *others, last = [repr(name) for name in ["auto", *families]]
            raise ValueError(f"model {self.model!r}: give {', '.join(others)} or {last}")
        if self.search == "none":
            # A family holds the parameters it does not move (kernel ridge's epsilon is 0).
            moved = families.get(self.model) or {a for axes in families.values() for a in axes}
            given = {"C": self.C, "epsilon": self.epsilon, "sigma": self.sigma}
            given = {name: value for name, value in given.items() if name.lower() in moved}
            if any(h is None for h in given.values()):
                raise ValueError(f"search='none' uses {', '.join(given)} as given: set them all")
        self._single_output = y.ndim == 1
        Y = y.reshape(-1, 1) if self._single_output else y
        groups = _labels(groups, X.shape[0])
        if time is not None:
            time = np.asarray(time, dtype=np.float64)
            if time.shape != (X.shape[0],):
                raise ValueError(f"time has shape {time.shape}; give one value per row of X "
                                 f"({X.shape[0]})")
            if not np.all(np.isfinite(time)):
                row = int(np.flatnonzero(~np.isfinite(time))[0])
                raise ValueError(f"row {row}: time {time[row]} is not a number of seconds")
        if weights is not None and not np.all(weights > 0):
            kept = weights > 0
            if time is not None:
                row = int(np.flatnonzero(~kept)[0])
                raise ValueError(f"row {row}: sample_weight 0 with time given; the history "
                                 "needs every row: give every row a weight above 0")
            if kept.sum() < _core.MIN_FIT_ROWS:
                raise ValueError(f"sample_weight leaves {kept.sum()} rows above 0; the fit "
                                 f"needs at least {_core.MIN_FIT_ROWS}")
            X, Y, weights = X[kept], Y[kept], weights[kept]
            groups = None if groups is None else groups[kept]
        seed = DEFAULT_SEED if self.random_state is None else self.random_state
        if not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**64:
            raise ValueError(f"random_state {seed!r}: give None or an int from 0 to 2**64 - 1")
        for name, value, least in (("budget", self.budget, 1), ("folds", self.folds, 2),
                                   ("max_iter", self.max_iter, 1)):
            if name == "budget" and value is None:
                continue
            if not isinstance(value, (int, np.integer)) or not least <= value < 2**63:
                raise ValueError(f"{name} {value!r}: give an int of at least {least}")
        names = [f"x{j}" for j in range(X.shape[1])]
        if hasattr(self, "feature_names_in_"):
            names = [str(n) for n in self.feature_names_in_]
        self.model_ = _core.fit(
            np.ascontiguousarray(X), np.ascontiguousarray(Y, dtype=np.float64),
            input_names=names, output_names=[f"y{j}" for j in range(Y.shape[1])],
            model=str(self.model), c=None if self.C is None else float(self.C),
            epsilon=None if self.epsilon is None else float(self.epsilon),
            sigma=None if self.sigma is None else float(self.sigma),
            loss=self.loss, basis=str(self.basis), budget=self.budget, folds=int(self.folds),
            groups=groups, time=time, weights=weights, history=str(self.history),
            seed=int(seed),
            tol=float(self.tol), max_iter=int(self.max_iter), intervals=bool(self.intervals))
        self.C_, self.epsilon_, self.sigma_ = self.model_.hyper
        self.support_vectors_ = self.model_.support_vectors
        self.dual_coef_ = self.model_.dual_coef
        self.intercept_ = self.model_.intercept
        self.n_iter_ = self.model_.iterations
        self.family_ = self.model_.family
        import json
        search = self.model_.search
        self.search_ = None if search is None else json.loads(search)
        return self

    def predict(self, X, time=None, groups=None):
        """The model's outputs for each row of X: (n,) for a single-output fit, else (n, q). A
        model that sees its inputs' history needs each row's `time` (and `groups`, when it was
        fitted with them), rows in time order within each group."""
        check_is_fitted(self)
        X = validate_data(self, X, reset=False, dtype=np.float64)
        if time is not None:
            time = np.ascontiguousarray(time, dtype=np.float64)
        groups = _labels(groups, X.shape[0])
        Y = self.model_.predict(np.ascontiguousarray(X), time=time, groups=groups)
        return Y.ravel() if self._single_output else Y

    def jacobian(self, X):
        """d outputs / d inputs at each row of X: (n, q, d), exact (the kernel's derivative).
        A model that sees its inputs' history gives its steady state's (every filter settled at
        the row's inputs): the map a feed-forward controller inverts."""
        check_is_fitted(self)
        X = validate_data(self, X, reset=False, dtype=np.float64)
        return self.model_.jacobian(np.ascontiguousarray(X))

    def interval_radius(self, level=0.9, X=None, time=None, groups=None):
        """The conformal interval's radius at `level` (output units): the truth lies within it
        of the prediction that share of the time (marginal over rows like the held-out ones).
        Calibrated on the held-out predictions of the search's folds (or, with C, epsilon and
        sigma all given and intervals=True, the same kind of folds).

        The radius widens where the inputs are farther from the training rows than the held-out
        rows were: without X, the radius where they are not (a number); with X (and `time`,
        `groups` as `predict` takes them), each row's radius, (n,), as `handcap predict
        --interval` writes it."""
        check_is_fitted(self)
        if X is None:
            return self.model_.interval_radius(level)
        X = validate_data(self, X, reset=False, dtype=np.float64)
        if time is not None:
            time = np.ascontiguousarray(time, dtype=np.float64)
        groups = _labels(groups, X.shape[0])
        return self.model_.interval_radii(np.ascontiguousarray(X), level, time=time, groups=groups)

    def inverse(self, targets, max_kpa=None, reach=0.01):
        """(inputs, achieved, error, reached) for each target row, as `handcap inverse`."""
        check_is_fitted(self)
        T = np.asarray(targets, dtype=np.float64)
        T = T.reshape(-1, 1) if T.ndim == 1 and self._single_output else np.atleast_2d(T)
        return self.model_.inverse(np.ascontiguousarray(T), max_kpa=max_kpa, reach=reach)

    def save(self, path):
        """Writes the model file (`handcap predict` and `inverse` read it)."""
        check_is_fitted(self)
        self.model_.save(str(path))


class KernelRidgeRegressor(MSVRRegressor):
    """Kernel ridge regression with an intercept (the squared loss, no tube; scikit-learn's
    `KernelRidge` with alpha = 1/(2C), plus the intercept), over handcap's core: the family
    `handcap model --model krr` fits, its C and sigma searched by the same ant colony on the
    same folds as MSVRRegressor's, exact or on a reduced basis for many rows. Every method and
    fitted attribute is MSVRRegressor's (epsilon_ is 0); the model file is the command line's.

    Parameters
    ----------
    C, sigma : float or None
        Penalty (the ridge is 1/(2C)) and RBF width (inputs scaled to [0, 1]); None: searched.
    search, budget, basis, folds, history, intervals, random_state, tol, max_iter :
        as MSVRRegressor's.
    """

    model = "krr"
    epsilon = None
    loss = "robust"

    def __init__(self, C=None, sigma=None, search="aco-r", budget=None, basis="auto", folds=5,
                 history="auto", random_state=None, tol=1e-8, max_iter=500, intervals=False):
        self.C = C
        self.sigma = sigma
        self.search = search
        self.budget = budget
        self.basis = basis
        self.folds = folds
        self.history = history
        self.random_state = random_state
        self.tol = tol
        self.max_iter = max_iter
        self.intervals = intervals


def _labels(groups, rows):
    """`groups` as float64 labels, or None: numbers as they are, other labels (names) as the
    rank of their first appearance, as the command line reads a group column. The order
    matters to the intervals, whose folds are blocks of consecutive runs."""
    if groups is None:
        return None
    groups = np.asarray(groups)
    if groups.shape != (rows,):
        raise ValueError(f"groups has shape {groups.shape}; give one value per row of X ({rows})")
    if np.issubdtype(groups.dtype, np.number) and np.all(np.isfinite(groups)):
        return groups.astype(np.float64)
    _, first, inverse = np.unique(groups, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.float64)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[inverse]
