from os import PathLike
from typing import Any, Optional, Sequence, Tuple, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray
from sklearn.base import BaseEstimator, RegressorMixin

MIN_FIT_ROWS: int
__version__: str

class Model:
    """A fitted model: from MSVRRegressor.fit, or a model file any `handcap model` run wrote."""

    @staticmethod
    def load(path: Union[str, PathLike[str]]) -> "Model": ...
    @staticmethod
    def from_json(text: str) -> "Model": ...
    def to_json(self) -> str: ...
    def save(self, path: Union[str, PathLike[str]]) -> None: ...
    def predict(
        self,
        x: NDArray[np.float64],
        time: Optional[NDArray[np.float64]] = None,
        groups: Optional[NDArray[np.float64]] = None,
    ) -> NDArray[np.float64]: ...
    def jacobian(self, x: NDArray[np.float64]) -> NDArray[np.float64]: ...
    def inverse(
        self, targets: NDArray[np.float64], max_kpa: float | None = None, reach: float = 0.01
    ) -> Tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]: ...
    @property
    def inputs(self) -> list[str]: ...
    @property
    def feature_names(self) -> list[str]: ...
    @property
    def outputs(self) -> list[str]: ...
    @property
    def family(self) -> str: ...
    @property
    def hyper(self) -> Tuple[float, float, float]: ...
    @property
    def support_vectors(self) -> NDArray[np.float64]: ...
    @property
    def dual_coef(self) -> NDArray[np.float64]: ...
    @property
    def intercept(self) -> NDArray[np.float64]: ...
    @property
    def iterations(self) -> int: ...
    @property
    def basis(self) -> str: ...
    @property
    def search(self) -> Optional[str]: ...
    @property
    def history(self) -> Optional[str]: ...
    def interval_radius(self, level: float) -> float: ...

def load(path: Union[str, PathLike[str]]) -> Model: ...

class MSVRRegressor(RegressorMixin, BaseEstimator):
    C: Optional[float]
    epsilon: Optional[float]
    sigma: Optional[float]
    search: str
    budget: Optional[int]
    loss: str
    basis: Union[str, int]
    folds: int
    history: str
    random_state: Optional[int]
    tol: float
    max_iter: int
    C_: float
    epsilon_: float
    sigma_: float
    support_vectors_: NDArray[np.float64]
    dual_coef_: NDArray[np.float64]
    intercept_: NDArray[np.float64]
    n_iter_: int
    n_features_in_: int
    model_: Model
    family_: str
    search_: Optional[dict[str, Any]]
    def __init__(
        self,
        C: Optional[float] = None,
        epsilon: Optional[float] = None,
        sigma: Optional[float] = None,
        model: str = "msvr",
        search: str = "aco-r",
        budget: Optional[int] = None,
        loss: str = "robust",
        basis: Union[str, int] = "auto",
        folds: int = 5,
        history: str = "auto",
        random_state: Optional[int] = None,
        tol: float = 1e-8,
        max_iter: int = 500,
        intervals: bool = False,
    ) -> None: ...
    def fit(
        self,
        X: ArrayLike,
        y: ArrayLike,
        groups: Optional[ArrayLike] = None,
        time: Optional[ArrayLike] = None,
        sample_weight: Optional[ArrayLike] = None,
    ) -> "MSVRRegressor": ...
    def predict(
        self, X: ArrayLike, time: Optional[ArrayLike] = None, groups: Optional[ArrayLike] = None
    ) -> NDArray[np.float64]: ...
    def jacobian(self, X: ArrayLike) -> NDArray[np.float64]: ...
    def interval_radius(self, level: float = 0.9) -> float: ...
    def inverse(
        self, targets: ArrayLike, max_kpa: float | None = None, reach: float = 0.01
    ) -> Tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]: ...
    def save(self, path: Union[str, PathLike[str]]) -> None: ...

class KernelRidgeRegressor(MSVRRegressor):
    def __init__(
        self,
        C: Optional[float] = None,
        sigma: Optional[float] = None,
        search: str = "aco-r",
        budget: Optional[int] = None,
        basis: Union[str, int] = "auto",
        folds: int = 5,
        history: str = "auto",
        random_state: Optional[int] = None,
        tol: float = 1e-8,
        max_iter: int = 500,
        intervals: bool = False,
    ) -> None: ...
