import os
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, TypedDict, Union

import numpy as np
import numpy.typing as npt

__version__: str

ArrayLike = npt.ArrayLike
PathOrText = Union[str, "os.PathLike[str]"]

class DiagnosticDict(TypedDict):
    severity: str
    message: str
    file: str
    line: Optional[int]
    column: Optional[int]
    end_line: Optional[int]
    end_column: Optional[int]
    label: Optional[str]
    hint: Optional[str]
    hints: List[str]
    rendered: str

class LobeError(Exception):
    """A formula, scene or argument lobe cannot take; ``diagnostics`` says where and why."""

    diagnostics: List[DiagnosticDict]

class FitCandidate(TypedDict):
    params: Dict[str, float]
    score: float
    refined: bool

class FitResult(TypedDict):
    params: Dict[str, float]
    score: float
    loss: str
    evaluated: int
    best: List[FitCandidate]

def compile(path_or_text: PathOrText, *, math: str = "precise", **baked: float) -> Kernel:
    """Compile a formula (a path if it names an existing file, else formula text), ``baked`` parameters as constants."""

class Kernel:
    """A compiled formula: call it with inputs (NL, NV, NH, VR, VH or L, V of shape (..., 3)) and parameters."""

    @property
    def name(self) -> str: ...
    @property
    def file(self) -> str: ...
    @property
    def source(self) -> str: ...
    @property
    def math(self) -> str: ...
    @property
    def baked(self) -> Dict[str, float]: ...
    @property
    def params(self) -> Dict[str, float]: ...
    @property
    def param_ranges(self) -> Dict[str, Tuple[float, float]]: ...
    @property
    def inputs(self) -> Tuple[str, ...]: ...
    @property
    def channels(self) -> int: ...
    @property
    def compiled(self) -> Tuple[str, ...]: ...
    def __call__(self, *, out: Optional[npt.NDArray[np.float64]] = None, **inputs_and_params: ArrayLike) -> npt.NDArray[np.float64]:
        """Values at every point; inputs and parameters (one value or one per point) broadcast together."""
    def check(self, *, points: int = 100_000, budget: float = 10.0) -> Dict[str, Any]: ...
    def energy(
        self,
        *,
        mode: str = "lobe",
        lobe: Optional[str] = None,
        range: Optional[Tuple[float, float]] = None,
        step: float = 1.0,
        against: Optional[Kernel] = None,
        **params: float,
    ) -> Dict[str, Any]:
        """``lobe energy --json``; ``range=(lo, hi)`` sweeps n (``--range``, ``--step``), scored ``against`` a fitted coefficient."""
    def accuracy(self, reference: Kernel, *, q: float = 8.0, n_max: int = 1000, epicenter_from: int = 2, **params: float) -> Dict[str, Any]:
        """``lobe accuracy --json``, per channel for a colour formula (``"channels"``)."""
    def sweep(self, *, bound: float = 1e6, max_evals: int = 2_000_000, as_written: bool = False) -> Dict[str, Any]: ...
    def grad(self, **inputs_and_params: ArrayLike) -> Dict[str, npt.NDArray[np.float64]]:
        """Partial derivative by every parameter and every input read, name → array (``lobe eval --grad``'s bits)."""
    def jacobian(self, params: Optional[Sequence[str]] = None, **inputs_and_params: ArrayLike) -> npt.NDArray[np.float64]:
        """(values, parameters) Jacobian for ``scipy.optimize.least_squares``; rows in ``np.ravel`` order of the values."""
    def sample(self, wi: ArrayLike, u: ArrayLike, **params: float) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """(wo, pdf, weight) for incident ``wi`` (..., 3) and uniforms ``u`` (..., 2), broadcast together; weight = f·cosθₒ/pdf."""
    def pdf(self, wi: ArrayLike, wo: ArrayLike, **params: float) -> npt.NDArray[np.float64]:
        """The sampler's density of ``wo`` given ``wi`` (both (..., 3)): the pdf ``sample`` reports."""
    @property
    def sampler_mechanism(self) -> Optional[str]: ...

def fit(
    kernel: Kernel,
    target: ArrayLike,
    params: Mapping[str, Union[Tuple[float, float], Tuple[float, float, float]]],
    *,
    weights: Optional[ArrayLike] = None,
    loss: str = "mse",
    top: int = 5,
    refine: bool = True,
    **inputs: ArrayLike,
) -> FitResult:
    """Fit ``params`` (name → (lo, hi) or (lo, hi, step)) of ``kernel`` to ``target`` at ``inputs``."""

class Image(np.ndarray):
    """An (H, W, 3) uint8 image that a notebook shows."""

    def _repr_png_(self) -> bytes: ...
    def png(self) -> bytes: ...
    def save(self, path: PathOrText) -> None: ...

def render(
    scene: PathOrText,
    *,
    size: Union[None, int, Tuple[int, int]] = None,
    aa: Optional[int] = None,
    srgb: bool = False,
    threads: int = 0,
    math: str = "precise",
    backend: str = "jit",
    tier: str = "auto",
    **params: float,
) -> Image:
    """Render a scene file as ``lobe render`` does (``math``, ``backend``, ``tier``: its flags and defaults)."""
