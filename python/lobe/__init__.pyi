import os
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, TypedDict, Union, overload

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
    def tabulate(self, path: Optional[PathOrText] = None, *, color: Sequence[float] = (1.0, 1.0, 1.0), **params: float) -> Measured:
        """The formula at the MERL convention's angles (``lobe tabulate``), saved to ``path`` if given."""
    def export(self, format: str = "glsl", *, glsl_version: str = "450", mechanism: str = "auto", **params: float) -> str:
        """``lobe export``: ``"glsl"``, ``"wgsl"``, ``"brdf"`` (BRDF Explorer) or ``"mitsuba"``; ``params`` baked."""
    def bench(
        self,
        *,
        reference: Optional[Kernel] = None,
        math: str = "precise",
        samples: int = 31,
        timing_points: int = 4096,
        albedo: bool = True,
        tier: str = "auto",
        **params: float,
    ) -> Dict[str, Any]:
        """One row of ``lobe bench --json`` (``"channels"``: a colour formula's three rows)."""

class Measured:
    """A MERL table (90 × 90 × 180 entries per channel, red, green, blue)."""

    entries: int
    channels: int
    @property
    def name(self) -> str: ...
    @property
    def path(self) -> Optional[str]: ...
    @property
    def measured_entries(self) -> int: ...
    def values(self, wi: ArrayLike, wo: ArrayLike, *, lookup: str = "linear") -> npt.NDArray[np.float64]:
        """The lookup at directions ``wi`` (L) and ``wo`` (V) of shape (..., 3): values of shape (..., 3)."""
    def to_bytes(self) -> bytes: ...
    def save(self, path: PathOrText) -> Measured: ...

def load_measured(path: PathOrText) -> Measured:
    """Read a MERL ``.binary`` table."""

@overload
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
@overload
def fit(
    kernel: Kernel,
    target: Union[Measured, Kernel],
    params: Mapping[str, Union[Tuple[float, float], Tuple[float, float, float]]],
    *,
    top: int = 5,
    refine: bool = True,
    metric: Optional[str] = None,
    fit_scale: Optional[bool] = None,
    set: Optional[Mapping[str, float]] = None,
    stride: int = 1,
    grid_stride: int = 4,
    n_max: int = 1000,
    derivative_free: bool = False,
) -> Dict[str, Any]:
    """``lobe fit --measured TABLE`` (a :class:`Measured`) or ``--reference`` (a :class:`Kernel`): the command's JSON."""

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

def compare(
    a: Union[Kernel, Measured],
    b: Union[Kernel, Measured],
    *,
    scene: Optional[PathOrText] = None,
    size: Union[None, int, Tuple[int, int]] = None,
    threads: int = 0,
    srgb: bool = False,
    math: str = "precise",
    backend: str = "jit",
    **params: float,
) -> Dict[str, Any]:
    """``lobe compare --json`` with the images ``a``, ``b``, ``difference`` and ``figure`` (file names: ``a_name``, ``b_name``)."""

def plot(
    *items: Union[Kernel, Measured],
    incidence: Optional[float] = None,
    log: bool = False,
    ylim: Optional[Tuple[float, float]] = None,
    polar: bool = False,
    size: Tuple[int, int] = (900, 600),
    reference: Optional[Kernel] = None,
    error: bool = False,
    lookup: str = "linear",
    **params: float,
) -> Tuple[Image, Dict[str, Any]]:
    """``lobe plot``: the picture and ``{"title", "x_label", "y_label", "x", "y": {name: array}}``."""
