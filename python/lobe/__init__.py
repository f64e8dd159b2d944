"""lobe: BRDF formulas (.brdf files) compiled to fast, accurate kernels for numpy.

>>> import lobe, numpy as np
>>> k = lobe.compile("examples/brdfs/blinn.brdf")
>>> k(NH=np.linspace(0, 1, 5), n=100)

A :class:`Kernel` evaluates on numpy arrays (broadcast together) of cosines (``NL``, ``NV``, ``NH``, ``VR``,
``VH``) or of directions ``L`` and ``V`` of shape ``(..., 3)`` in the local frame (N = +z); parameters are
given by name, as one value or an array broadcast with the inputs, and default to the formula's declared
values. The values are the ones ``lobe eval --points``
prints, bit for bit. The checks (:meth:`Kernel.check`, :meth:`Kernel.energy`, :meth:`Kernel.accuracy`,
:meth:`Kernel.sweep`) return the dicts the command line prints with ``--json``. :func:`fit` fits parameters to
target values, to a measured table (:func:`load_measured`, :meth:`Kernel.tabulate`) or to another formula;
:func:`render` renders a scene file to an image a notebook shows, :func:`compare` two formulas' renders and
:func:`plot` their lobes; :meth:`Kernel.export` writes shaders and plugins, :meth:`Kernel.bench` a bench row.

Errors are :class:`LobeError`, whose ``diagnostics`` list says where (file, line, column) and why.
"""

from __future__ import annotations

import errno
import os
import re
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _lobe
from ._lobe import LobeError

__all__ = ["compile", "Kernel", "LobeError", "fit", "render", "Image", "Measured", "load_measured", "compare", "plot", "__version__"]
__version__: str = _lobe.__version__

_NAMES = ("NL", "NV", "NH", "VR", "VH")
# One line of path characters ending in a file extension that starts with a letter (`.brdf`, `.txt`): no formula
# has that shape (`NH/2.5` ends in digits; calls and operators other than `/` and `-` are not path characters).
_PATH_LIKE = re.compile(r"[\w~./\\\-]*\.[A-Za-z]\w*")


def __dir__() -> list:
    """The public names only (not the modules and types the implementation imports)."""
    return sorted(set(__all__ + ["__version__"]))


def _error(message: str, hint: Optional[str] = None) -> LobeError:
    """A LobeError raised on the Python side, with one place-less diagnostic."""
    text = f"error: {message}" + (f"\n  = help: {hint}" if hint else "")
    e = LobeError(text)
    e.diagnostics = [
        {
            "severity": "error",
            "message": message,
            "file": "",
            "line": None,
            "column": None,
            "end_line": None,
            "end_column": None,
            "label": None,
            "hint": hint,
            "hints": [hint] if hint else [],
            "rendered": text + "\n",
        }
    ]
    return e


def _not_none(name: str, value: Any) -> None:
    """None is no number: numpy would read it as NaN."""
    if value is None:
        raise _error(f"`{name}` is None", f"give {name} a number or an array, or leave a parameter out for its default")


def _flat(a: Any, shape: Tuple[int, ...], tail: Tuple[int, ...] = ()) -> np.ndarray:
    """``a`` broadcast to ``shape + tail`` as C-contiguous, aligned float64, flattened to ``(-1,) + tail``: no
    copy when it already is (arrays unpickled from out-of-band buffers may be unaligned: those are copied)."""
    return np.require(np.broadcast_to(a, shape + tail), np.float64, ["C", "A"]).reshape((-1,) + tail)


def _read(path_or_text: Union[str, "os.PathLike[str]"]) -> Tuple[str, str]:
    """(file name, text): a path names an existing file; any other string is formula text."""
    if isinstance(path_or_text, os.PathLike):
        return _lobe.read_source(os.fspath(path_or_text))
    if not isinstance(path_or_text, str):
        raise TypeError(f"compile() takes a path or formula text, not {type(path_or_text).__name__}")
    s = path_or_text
    if "\n" not in s and len(s) < 4096 and os.path.isfile(s):
        return _lobe.read_source(s)
    if _PATH_LIKE.fullmatch(s.strip()):
        # `examples/brdfs/blin.brdf` is a mistyped path, not formula text ("unknown variable `examples`").
        raise FileNotFoundError(errno.ENOENT, "file not found (text shaped like a path is not read as a formula)", s)
    return "<text>", s


def compile(path_or_text: Union[str, "os.PathLike[str]"], *, math: str = "precise", **baked: float) -> "Kernel":
    """Compile a formula: a path if it names an existing file, else formula text.

    ``math`` is ``"precise"`` (lobe's correctly-rounded-or-close builtins) or ``"fast"``. Keyword arguments are
    parameter values baked into the code as constants (``n=50``); the other parameters stay live and are given
    per call. The formula is compiled exactly as ``lobe eval`` compiles it (the accuracy pass included, its
    decisions cached on disk), so values match the command line bit for bit.
    """
    file, src = _read(path_or_text)
    return _compile_text(file, src, math, baked)


def _compile_text(file: str, src: str, math: str, baked: Mapping[str, float]) -> "Kernel":
    items = [(str(k), float(v)) for k, v in baked.items()]
    native, warnings = _lobe.compile(file, src, math, items)
    if warnings:
        import warnings as w

        w.warn(warnings.rstrip(), stacklevel=3)
    return Kernel._from_native(native)


def _rebuild(file: str, source: str, math: str, baked: Any) -> "Kernel":
    """Unpickling: compile again from the source text (in the worker process)."""
    return _compile_text(file, source, math, dict(baked))


class Kernel:
    """A compiled formula. Call it with inputs and parameters as keywords; see the module docs.

    Kernels pickle as their source text, baked values and math mode, and compile again where they are
    unpickled (a Dask or Ray worker, a multiprocessing pool).
    """

    __slots__ = ("_native", "_defaults", "_mechanism", "_scalar")

    def __init__(self, *_: Any, **__: Any) -> None:
        raise TypeError("use lobe.compile(path_or_text) to make a Kernel")

    @classmethod
    def _from_native(cls, native: Any) -> "Kernel":
        k = object.__new__(cls)
        k._native = native
        k._defaults = [p[1] for p in native.params]
        k._mechanism = None
        # The per-call path of calls with plain numbers: keyword → ("input" | "param", index) for the cosines
        # and the live parameters, and the inputs the kernels read (each must be given).
        baked = {b[0] for b in native.baked}
        names = [n for n in _NAMES] + [p[0] for p in native.params if p[0] not in baked]
        kinds = dict(zip(names, native.resolve(names)))
        read = tuple(i for i in native.inputs if i in _NAMES)
        direction = any(i not in _NAMES for i in native.inputs)
        k._scalar = None if direction else (kinds, read)
        return k

    # -- what it is -------------------------------------------------------------------------------------
    @property
    def name(self) -> str:
        """The formula's display name."""
        return self._native.name

    @property
    def file(self) -> str:
        """The file it was read from (``"<text>"`` for formula text)."""
        return self._native.file

    @property
    def source(self) -> str:
        """The formula's source text."""
        return self._native.source

    @property
    def math(self) -> str:
        """``"precise"`` or ``"fast"``."""
        return self._native.math

    @property
    def baked(self) -> Dict[str, float]:
        """Parameters baked into the code, by name."""
        return dict(self._native.baked)

    @property
    def params(self) -> Dict[str, float]:
        """Every declared parameter's default (declaration order, ``n`` first); baked ones at their value."""
        return {p[0]: p[1] for p in self._native.params}

    @property
    def param_ranges(self) -> Dict[str, Tuple[float, float]]:
        """Every declared parameter's range (lo, hi)."""
        return {p[0]: (p[2], p[3]) for p in self._native.params}

    @property
    def inputs(self) -> Tuple[str, ...]:
        """The inputs the compiled kernel reads (``NH``, ``Lx``, …)."""
        return tuple(self._native.inputs)

    @property
    def channels(self) -> int:
        """1 for a scalar formula, 3 for a colour one (values then have a trailing axis of 3)."""
        return self._native.channels

    @property
    def compiled(self) -> Tuple[str, ...]:
        """The formula lobe compiled, per channel, as program text."""
        return tuple(self._native.compiled)

    def __repr__(self) -> str:
        baked = "".join(f", {k}={v!r}" for k, v in self.baked.items())
        return f"<lobe.Kernel {self.name!r} from {self.file!r}, math={self.math!r}{baked}>"

    def __reduce__(self) -> Tuple[Any, Tuple[Any, ...]]:
        return (_rebuild, self._native.state())

    # -- evaluation -------------------------------------------------------------------------------------
    def _prepare(self, kw: Mapping[str, Any]) -> Tuple[list, Any, Any, list, list, Tuple[int, ...]]:
        """Split keywords into input columns and per-point parameter columns (broadcast together, contiguous
        float64, flattened) and the parameter vector; returns (cosines, L, V, params, varying, shape)."""
        kinds = self._native.resolve(list(kw))
        params = list(self._defaults)
        cos, dirs, per_point, shapes = [], {}, [], {}
        for (name, value), (kind, i) in zip(kw.items(), kinds):
            _not_none(name, value)
            a = np.asarray(value, dtype=np.float64)
            if kind == "param":
                shapes[name] = a.shape
                if a.size == 1:
                    params[i] = float(a.reshape(()))
                else:
                    per_point.append((i, a))
            elif kind == "input":
                shapes[name] = a.shape
                cos.append((i, a))
            else:
                if a.ndim == 0 or a.shape[-1] != 3:
                    raise _error(f"{name} must have shape (..., 3), not {a.shape}", f"{name} is a direction: x, y, z in the local frame (N = +z)")
                shapes[name] = a.shape[:-1]
                dirs[kind] = a
        try:
            shape = np.broadcast_shapes(*shapes.values()) if shapes else ()
        except ValueError:
            raise _error(f"the shapes of the inputs and parameters do not broadcast: {shapes}", "L and V count without their last axis (of 3)") from None
        flat = [(i, _flat(a, shape)) for i, a in cos]
        varying = [(i, _flat(a, shape)) for i, a in per_point]
        lv = [_flat(dirs[k], shape, (3,)) if k in dirs else None for k in ("L", "V")]
        return flat, lv[0], lv[1], params, varying, shape

    def __call__(self, *, out: Optional[np.ndarray] = None, **inputs_and_params: Any) -> np.ndarray:
        """Evaluate at every point: returns float64 of the broadcast shape (``(..., 3)`` for colour).

        Inputs and parameters broadcast together by numpy's rules: a parameter may be one value or an array
        (one value per point, e.g. ``k(NH=nh, n=np.array([[10], [100]]))`` for a table over n and NH); the
        value at each point is the one evaluating that point alone gives, bit for bit. The work runs without
        the GIL, split over threads for large arrays. ``out=`` (a writable C-contiguous float64 array of the
        result's shape) receives the values instead of a new array, and is returned: repeated calls on large
        arrays then allocate nothing."""
        fast = self._scalar
        if fast is not None and out is None:
            # Plain numbers naming cosines and live parameters, every read cosine given: one point, no arrays.
            kinds, read = fast
            params = None
            x = []
            for name, v in inputs_and_params.items():
                t = type(v)
                entry = kinds.get(name)
                if (t is not float and t is not int) or entry is None:
                    break
                if entry[0] == "param":
                    if params is None:
                        params = list(self._defaults)
                    params[entry[1]] = float(v)
                else:
                    x.append((entry[1], float(v)))
            else:
                if all(r in inputs_and_params for r in read):
                    out = self._native.eval_one(x, self._defaults if params is None else params)
                    return np.array(out[0]) if len(out) == 1 else np.array(out)
        cos, L, V, params, varying, shape = self._prepare(inputs_and_params)
        n = int(np.prod(shape, dtype=np.int64))
        if out is not None:
            want = shape if self.channels == 1 else shape + (self.channels,)
            ok = isinstance(out, np.ndarray) and out.dtype == np.float64 and out.flags.c_contiguous and out.flags.writeable
            if not ok or out.shape != want:
                raise _error(f"out must be a writable C-contiguous float64 array of shape {want}", "e.g. out=np.empty(shape) once, reused across calls")
            if self.channels == 1:
                self._native.eval_out((cos, L, V, n), params, varying, out.reshape(-1))
            else:
                values = self._native.eval((cos, L, V, n), params, varying)
                out[...] = np.moveaxis(values.reshape((self.channels,) + shape), 0, -1)
            return out
        values = self._native.eval((cos, L, V, n), params, varying)
        if self.channels == 1:
            return values.reshape(shape)
        return np.moveaxis(values.reshape((self.channels,) + shape), 0, -1)

    # -- derivatives (docs/derivatives.md) ------------------------------------------------------------------
    def _grad(self, kw: Mapping[str, Any]) -> Tuple[List[str], np.ndarray, np.ndarray, Tuple[int, ...]]:
        """(names, values (channels, n), partials (variables, channels, n), shape) at the keywords' points."""
        cos, L, V, params, varying, shape = self._prepare(kw)
        if varying:
            raise _error("a gradient takes one value per parameter", "give each parameter one number (evaluate several parameter sets with several calls)")
        n = int(np.prod(shape, dtype=np.int64))
        names, values, grads = self._native.grad((cos, L, V, n), params)
        ch = self.channels
        return list(names), values.reshape((ch, n)), grads.reshape((len(names), ch, n)), shape

    def _shaped(self, a: np.ndarray, shape: Tuple[int, ...]) -> np.ndarray:
        """One output (channels, n) in the broadcast shape (``(..., 3)`` for colour)."""
        if self.channels == 1:
            return a.reshape(shape)
        return np.moveaxis(a.reshape((self.channels,) + shape), 0, -1)

    def grad(self, **inputs_and_params: Any) -> Dict[str, np.ndarray]:
        """The partial derivatives at every point: name → array of the broadcast shape (``(..., 3)`` for colour),
        for every declared parameter (``n`` first; baked ones too) and every input the formula reads (cosines, or
        ``Lx`` … ``Vz`` for a formula that reads directions). The numbers of ``lobe eval --grad``, bit for bit: one
        compiled value-and-gradient kernel, exact derivatives with the kink rules of docs/derivatives.md (never
        NaN where the derivative is finite). Inputs broadcast as for a call; each parameter takes one value."""
        names, _, grads, shape = self._grad(inputs_and_params)
        return {name: self._shaped(g, shape) for name, g in zip(names, grads)}

    def jacobian(self, params: Optional[Sequence[str]] = None, **inputs_and_params: Any) -> np.ndarray:
        """The Jacobian of the values with respect to ``params`` (default: every parameter that is not baked, in
        declaration order), shaped for ``scipy.optimize.least_squares``: one row per value (the points in the
        order ``np.ravel`` gives the values, the channels of a colour formula fastest), one column per parameter."""
        baked = set(self.baked)
        wanted = [p for p in self.params if p not in baked] if params is None else list(params)
        names, _, grads, shape = self._grad(inputs_and_params)
        for p in wanted:
            if p not in self.params:
                raise _error(f"`{p}` is not a parameter of the formula", f"parameters are: {', '.join(self.params)}")
        cols = [self._shaped(grads[names.index(p)], shape).reshape(-1) for p in wanted]
        n = int(np.prod(shape, dtype=np.int64)) * self.channels
        return np.stack(cols, axis=1) if cols else np.zeros((n, 0))

    # -- sampling (docs/sampling.md) ---------------------------------------------------------------------
    def sample(self, wi: Any, u: Any, **params: float) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Importance sampling of the outgoing direction: ``wo, pdf, weight = k.sample(wi, u)``.

        ``wi`` (shape ``(..., 3)``, the formula's L in the local frame, N = +z; normalised; above the horizon)
        and ``u`` (shape ``(..., 2)``, uniforms in [0, 1)) broadcast together over ``...``. Returns ``wo`` of
        shape ``(..., 3)``, ``pdf`` of shape ``(...)`` (the density per solid angle, equal to
        :meth:`pdf` at (wi, wo)) and ``weight`` = f(wi, wo)·cosθₒ/pdf of shape ``(...)`` (``(..., 3)`` for
        colour; 0 for a wo below the horizon). The sampler (``lobe sample``'s, built from this kernel at
        ``params``) is kept for the next calls at the same parameters; :attr:`sampler_mechanism` names its
        mechanism after a call."""
        wi_a, u_a = np.asarray(wi, dtype=np.float64), np.asarray(u, dtype=np.float64)
        if wi_a.ndim == 0 or wi_a.shape[-1] != 3:
            raise _error(f"wi must have shape (..., 3), not {wi_a.shape}", "wi is a direction: x, y, z in the local frame (N = +z)")
        if u_a.ndim == 0 or u_a.shape[-1] != 2:
            raise _error(f"u must have shape (..., 2), not {u_a.shape}", "u holds two uniforms in [0, 1) per sample")
        try:
            shape = np.broadcast_shapes(wi_a.shape[:-1], u_a.shape[:-1])
        except ValueError:
            raise _error(f"the shapes of wi {wi_a.shape} and u {u_a.shape} do not broadcast", "they count without their last axis (3 and 2)") from None
        wo, pdf, weight, mech = self._native.sample(_flat(wi_a, shape, (3,)), _flat(u_a, shape, (2,)), self._param_list(params))
        self._mechanism = mech
        weight = weight.reshape(shape + ((self.channels,) if self.channels > 1 else ()))
        return wo.reshape(shape + (3,)), pdf.reshape(shape), weight

    def pdf(self, wi: Any, wo: Any, **params: float) -> np.ndarray:
        """The sampler's density (per solid angle) of ``wo`` given ``wi``, both of shape ``(..., 3)`` broadcast
        together (normalised; wi above the horizon): the pdf :meth:`sample` reports, bit for bit."""
        wi_a, wo_a = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
        for name, a in (("wi", wi_a), ("wo", wo_a)):
            if a.ndim == 0 or a.shape[-1] != 3:
                raise _error(f"{name} must have shape (..., 3), not {a.shape}", f"{name} is a direction: x, y, z in the local frame (N = +z)")
        try:
            shape = np.broadcast_shapes(wi_a.shape[:-1], wo_a.shape[:-1])
        except ValueError:
            raise _error(f"the shapes of wi {wi_a.shape} and wo {wo_a.shape} do not broadcast", "they count without their last axis (3)") from None
        return self._native.pdf(_flat(wi_a, shape, (3,)), _flat(wo_a, shape, (3,)), self._param_list(params)).reshape(shape)

    @property
    def sampler_mechanism(self) -> Optional[str]:
        """The mechanism of the sampler the last :meth:`sample` used (``"tabulated"``, ``"exact"`` or
        ``"cosine"``; docs/sampling.md), None before the first."""
        return self._mechanism

    # -- the checks (the CLI's --json reports) ----------------------------------------------------------
    def _param_list(self, params: Mapping[str, float]) -> list:
        kinds = self._native.resolve(list(params))
        values = list(self._defaults)
        for (name, v), (kind, i) in zip(params.items(), kinds):
            _not_none(name, v)
            if kind != "param":
                raise _error(f"`{name}` is an input, not a parameter", "the checks choose their own inputs")
            values[i] = float(v)
        return values

    def check(self, *, points: int = 100_000, budget: float = 10.0) -> Dict[str, Any]:
        """What lobe made of the formula and its accuracy report: ``lobe check --json`` (the red channel of
        a colour formula)."""
        if isinstance(points, bool) or not isinstance(points, (int, np.integer)) or points < 1:
            raise _error(f"points = {points!r}: a whole number ≥ 1", "e.g. points=100_000 (the default)")
        return self._native.check(int(points), float(budget))

    def energy(
        self,
        *,
        mode: str = "lobe",
        lobe: Optional[str] = None,
        range: Optional[Tuple[float, float]] = None,
        step: float = 1.0,
        against: Optional["Kernel"] = None,
        **params: float,
    ) -> Dict[str, Any]:
        """The energy check: ``lobe energy --json``.

        ``mode="lobe"``: the papers' normalisation coefficient along ``lobe`` (``"NH"`` or ``"VR"``, default the
        one read); ``mode="full"``: the albedo over incidence angles and reciprocity. A colour formula adds
        ``"channels"`` (red, green, blue). ``range=(lo, hi)`` sweeps n over lo, lo + ``step``, … ≤ hi (lobe
        mode, scalar formulas, n not baked; ``--range``/``--step``): ``"range"`` lists ``{"n", "coef"}``, and
        ``against``, a kernel of n (and the formula's parameters, by name) giving a fitted coefficient, adds
        ``"against_max_abs"``, ``"against_worst_n"`` and ``"against_mean_abs"`` (``|coef_fit·2π·Int − 1|``)."""
        if against is not None and not isinstance(against, Kernel):
            raise TypeError("against must be a lobe.Kernel (lobe.compile(path_or_text))")
        rng = None
        if range is not None:
            r = tuple(range)
            if len(r) != 2:
                raise _error(f"range is (lo, hi), not {range!r}", "e.g. range=(1, 1000)")
            if "n" in params:
                raise _error("the range sweeps n", "give only the other parameters")
            rng = (float(r[0]), float(r[1]))
        return self._native.energy(mode, lobe, self._param_list(params), rng, float(step), None if against is None else against._native)

    def accuracy(self, reference: "Kernel", *, q: float = 8.0, n_max: int = 1000, epicenter_from: int = 2, **params: float) -> Dict[str, Any]:
        """The papers' error metrics against ``reference`` (its red channel if coloured) over n = 1..n_max:
        ``lobe accuracy --json``. ``params`` are live values of the formula's other parameters (n is swept);
        the reference runs at its declared values and those baked into it (``lobe.compile(ref, m=0.2)``). A
        colour formula is measured per channel: the red channel's keys, and ``"channels"`` with all three
        (red, green, blue)."""
        if not isinstance(reference, Kernel):
            raise TypeError("reference must be a lobe.Kernel (lobe.compile(path))")
        if "n" in params:
            raise _error("accuracy sweeps n itself", "give only the other parameters")
        return self._native.accuracy(reference._native, self._param_list(params), float(q), int(n_max), int(epicenter_from))

    def sweep(self, *, bound: float = 1e6, max_evals: int = 2_000_000, as_written: bool = False) -> Dict[str, Any]:
        """NaN, infinities, negative values and values over ``bound`` over the domain: ``lobe sweep --json``
        (``{"channels": {...}}`` for a colour formula)."""
        return self._native.sweep(float(bound), int(max_evals), bool(as_written))


    # -- tables, exports, bench rows (the CLI's tabulate, export and bench) --------------------------------
    def _set_list(self, params: Mapping[str, float], what: str) -> List[Tuple[str, float]]:
        """``params`` as (name, value) pairs of declared parameters, not baked (a name it does not declare has a
        did-you-mean hint)."""
        kinds = self._native.resolve(list(params))
        out = []
        for (name, v), (kind, _) in zip(params.items(), kinds):
            _not_none(name, v)
            if kind != "param":
                raise _error(f"`{name}` is an input, not a parameter", f"{what} takes parameter values only")
            out.append((name, float(v)))
        return out

    def tabulate(self, path: Union[None, str, "os.PathLike[str]"] = None, *, color: Sequence[float] = (1.0, 1.0, 1.0), **params: float) -> "Measured":
        """The formula at the MERL table convention's angles, as ``lobe tabulate`` writes it: a :class:`Measured`
        (``--color``: each channel times its factor; the parameters at ``params``, else their defaults). With
        ``path`` (a ``.binary`` file) the table is also saved there, the command's file byte for byte."""
        c = tuple(float(x) for x in color)
        if len(c) != 3:
            raise _error(f"color takes three factors, not {len(c)}", "e.g. color=(1, 0.8, 0.4)")
        m = Measured._from_native(_lobe.tabulate(self._native, self._param_list(params), c))
        if path is not None:
            m = m.save(path)
        return m

    def export(self, format: str = "glsl", *, glsl_version: str = "450", mechanism: str = "auto", **params: float) -> str:
        """The formula as ``lobe export`` writes it: ``format`` is ``"glsl"`` (``glsl_version`` ``"450"``,
        ``"330"`` or ``"es300"``), ``"wgsl"``, ``"brdf"`` (a file Disney's BRDF Explorer loads) or ``"mitsuba"``
        (a Python module registering a Mitsuba 3 plugin, every parameter baked; ``mechanism`` its sampler's,
        ``"auto"``, ``"tabulated"``, ``"exact"`` or ``"cosine"``). ``params`` and the kernel's baked values are
        baked as constants (``--set``); the other parameters become the shader function's arguments."""
        return _lobe.export(self._native, str(format), self._set_list(params, "export"), str(glsl_version), str(mechanism))

    def bench(
        self,
        *,
        reference: Optional["Kernel"] = None,
        math: str = "precise",
        samples: int = 31,
        timing_points: int = 4096,
        albedo: bool = True,
        tier: str = "auto",
        **params: float,
    ) -> Dict[str, Any]:
        """One row of ``lobe bench --json`` for this formula: compile time, ns/eval of each path, the error
        against ``reference`` (default: the catalogue's Blinn lobe) over n = 1..1000, the energy columns, with
        the command's keys. The timings and energy run at ``params`` and the baked values (n = 50 unless given),
        in ``math`` (``"precise"`` or ``"fast"``); ``samples``, ``timing_points``, ``albedo=False`` and ``tier``
        are ``--samples``, ``--timing-points``, ``--no-albedo`` and ``--tier``. A colour formula is measured per
        channel: the red channel's row, and ``"channels"`` with the three rows."""
        if reference is not None and not isinstance(reference, Kernel):
            raise TypeError("reference must be a lobe.Kernel (lobe.compile(path))")
        rows = _lobe.bench(
            self._native, None if reference is None else reference._native, self._set_list(params, "bench"), str(math), int(samples), int(timing_points), bool(albedo), str(tier)
        )
        if len(rows) == 1:
            return rows[0]
        return dict(rows[0], channels=rows)


def _free(kernel: Kernel, params: Mapping[str, Any]) -> List[Tuple[int, float, float, Optional[float]]]:
    """The searched parameters as (index, lo, hi, step or None)."""
    names = list(kernel.params)
    free = []
    for name, rng in params.items():
        if name not in names:
            kernel._native.resolve([name])  # raises with a did-you-mean hint
            raise _error(f"`{name}` is not a parameter")
        r = tuple(rng)
        if len(r) not in (2, 3):
            raise _error(f"the range of `{name}` is (lo, hi) or (lo, hi, step), not {rng!r}")
        free.append((names.index(name), float(r[0]), float(r[1]), float(r[2]) if len(r) == 3 else None))
    return free


def fit(
    kernel: Kernel,
    target: Any,
    params: Mapping[str, Union[Tuple[float, float], Tuple[float, float, float]]],
    *,
    weights: Any = None,
    loss: str = "mse",
    top: int = 5,
    refine: bool = True,
    metric: Optional[str] = None,
    fit_scale: Optional[bool] = None,
    set: Optional[Mapping[str, float]] = None,
    stride: int = 1,
    grid_stride: int = 4,
    n_max: int = 1000,
    derivative_free: bool = False,
    **inputs: Any,
) -> Dict[str, Any]:
    """Fit ``kernel``'s parameters to ``target``: values at points, a measured table, or another formula.

    ``params`` names the parameters to search, each with its range ``(lo, hi)`` (the interval [lo, hi]: a grid
    of 41 values, every integer when both ends are integers at least 40 apart, then continuous refinement) or
    ``(lo, hi, step)``.

    **Values at points** (``target`` an array): other parameters may be fixed among ``inputs`` by name.
    ``target`` (and ``weights``, ≥ 0) broadcast against the inputs (with a trailing axis of 3 for a colour
    formula). ``loss`` is ``"mse"`` (weighted least squares), ``"mae"`` or ``"max"``. The search scores every
    grid point (in parallel), then refines the best continuously (golden section for one parameter,
    Nelder–Mead for several) — lobe's fit optimiser. The result is deterministic: the same on any machine
    and thread count. Returns ``{"params": {name: value, …} (the best full vector), "score": …, "loss": …,
    "evaluated": …, "best": [{"params": …, "score": …, "refined": …}, …]}``.

    **A measured table** (``target`` a :class:`Measured`) is ``lobe fit --measured TABLE``: the formula at the
    table's entries (every ``stride``-th index per axis; the grid on every ``grid_stride``-th), ``metric``
    ``"log"`` (default), ``"rmse"`` or ``"cosine"``, each channel with its fitted colour scale.
    **A formula** (``target`` a :class:`Kernel`) is ``lobe fit --reference``: the papers' metric over n = 1..
    ``n_max`` (``metric`` ``"mean-abs"`` (default), ``"max-abs"`` or ``"epicenter"``) when both formulas read
    ``n``, else the whole hemisphere as against a table (``lobe fit --measured REF.brdf``; absolute values
    unless ``fit_scale=True``). ``set`` fixes parameter values (``--set``): each formula takes those it
    declares; a name both searched and set is the reference's value. Refinement is Levenberg–Marquardt with
    the exact Jacobian, or ``derivative_free=True`` (``--derivative-free``). Returns the command's ``--json``
    dict, plus ``"params"`` (the best searched values) — and against a table or over the hemisphere,
    ``"best"``: every candidate kept, with its ``"error"`` and colour ``"scale"``.
    """
    if not isinstance(kernel, Kernel):
        raise TypeError("fit() takes a lobe.Kernel first")
    if not params:
        raise _error("nothing to fit", "name at least one parameter with its range: params={'n': (1, 1000)}")
    if isinstance(target, (Measured, Kernel)):
        if inputs or weights is not None:
            given = ", ".join(list(inputs) + (["weights"] if weights is not None else []))
            raise _error(f"a fit against a table or a formula takes no points ({given})", "give fixed parameter values with set={...}")
        return _fit_against(kernel, target, params, metric, fit_scale, dict(set or {}), stride, grid_stride, top, refine, n_max, derivative_free)
    if set:
        raise _error("set= applies to fits against a table or a formula", "fix parameters among the inputs by name")
    if metric is not None or fit_scale is not None:
        raise _error("metric and fit_scale apply to fits against a table or a formula", "points are fitted under loss= (\"mse\", \"mae\" or \"max\")")
    cos, L, V, values, varying, shape = kernel._prepare(inputs)
    if varying:
        names = list(kernel.params)
        arrays = ", ".join(names[i] for i, _ in varying)
        raise _error(f"a fixed parameter takes one value in a fit, not an array ({arrays})", "fit once per value of the fixed parameters")
    n = int(np.prod(shape, dtype=np.int64))
    c = kernel.channels
    tshape = shape if c == 1 else shape + (c,)
    t = np.asarray(target, dtype=np.float64)
    try:
        t = np.broadcast_to(t, tshape)
    except ValueError:
        raise _error(f"target of shape {t.shape} does not match the inputs' shape {tshape}") from None
    t = _flat(np.moveaxis(t, -1, 0) if c > 1 else t, t.shape if c == 1 else (c,) + shape)
    w = None
    if weights is not None:
        try:
            w = _flat(np.asarray(weights, dtype=np.float64), shape)
        except ValueError:
            raise _error(f"weights do not match the inputs' shape {shape}") from None
    names = list(kernel.params)
    free = _free(kernel, params)
    best, evaluated = kernel._native.fit((cos, L, V, n), t, w, values, free, loss, int(top), bool(refine))
    cands = [{"params": dict(zip(names, p)), "score": s, "refined": r} for p, s, r in best]
    return {"params": cands[0]["params"], "score": cands[0]["score"], "loss": loss, "evaluated": evaluated, "best": cands}


class Image(np.ndarray):
    """A rendered image: an ``(H, W, 3)`` uint8 array that a notebook shows (``_repr_png_``)."""

    def _repr_png_(self) -> bytes:
        return self.png()

    def png(self) -> bytes:
        """The image as PNG bytes (lobe's encoder)."""
        a = np.ascontiguousarray(self, dtype=np.uint8)
        if a.ndim != 3 or a.shape[2] != 3:
            raise _error(f"an image has shape (H, W, 3), not {a.shape}")
        return _lobe.encode_png(a.view(np.ndarray).reshape(-1), a.shape[1], a.shape[0])

    def save(self, path: Union[str, "os.PathLike[str]"]) -> None:
        """Write the image as a PNG file."""
        with open(path, "wb") as f:
            f.write(self.png())


def render(
    scene: Union[str, "os.PathLike[str]"],
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
    """Render a scene file (.toml, see examples/scenes/) as ``lobe render`` does; ``params`` are given to every
    material whose formula declares them. ``size`` is N (square) or (width, height). ``math`` (``"precise"``
    or ``"fast"``), ``backend`` (``"jit"`` or ``"interp"``) and ``tier`` (``"cranelift"``, ``"llvm"`` in a
    build with that tier, or ``"auto"``) are the command's ``--math``, ``--backend`` and ``--tier``, with its
    defaults. Returns an :class:`Image` (``(H, W, 3)`` uint8)."""
    if isinstance(size, int):
        size = (size, size)
    wh = None if size is None else (int(size[0]), int(size[1]))
    rgb, w, h = _lobe.render(os.fspath(scene), wh, [(k, float(v)) for k, v in params.items()], aa, bool(srgb), int(threads), str(math), str(backend), str(tier))
    return np.frombuffer(rgb, dtype=np.uint8).reshape(h, w, 3).copy().view(Image)


def _fit_against(
    kernel: Kernel,
    target: Union["Measured", Kernel],
    params: Mapping[str, Any],
    metric: Optional[str],
    fit_scale: Optional[bool],
    fixed: Dict[str, float],
    stride: int,
    grid_stride: int,
    top: int,
    refine: bool,
    n_max: int,
    derivative_free: bool,
) -> Dict[str, Any]:
    """:func:`fit` against a table or a formula (the command's ``--measured`` and ``--reference``)."""
    ref = target if isinstance(target, Kernel) else None
    if ref is None and fit_scale is False:
        raise _error("a table's colour scale is always fitted (its calibration is unknown)", "drop fit_scale, or fit against a formula")
    names = list(kernel.params)
    ref_names = list(ref.params) if ref is not None else []
    for name, v in fixed.items():
        _not_none(name, v)
        if name not in names and name not in ref_names:
            known = list(dict.fromkeys(names + ref_names))
            raise _error(f"set: no formula has a parameter `{name}`", "the formulas' parameters are: " + ", ".join(known))
        if name in params and name not in ref_names:
            raise _error(f"`{name}` is both searched (params) and fixed (set)", "drop one of them")
    for what, v, lo in (("stride", stride, 1), ("grid_stride", grid_stride, 1), ("top", top, 1), ("n_max", n_max, 1)):
        if int(v) < lo:
            raise _error(f"{what} = {v} is below {lo}", "stride and grid_stride are 1..90; top and n_max at least 1")
    own = {k: v for k, v in fixed.items() if k in names and k not in params}
    values = kernel._param_list(own)
    ref_values = ref._param_list({k: v for k, v in fixed.items() if k in ref_names}) if ref is not None else []
    r = _lobe.fit_against(
        kernel._native,
        target._native,
        ref_values,
        values,
        _free(kernel, params),
        {
            "metric": metric,
            "fit_scale": bool(fit_scale),
            "stride": int(stride),
            "grid_stride": int(grid_stride),
            "top": int(top),
            "refine": bool(refine),
            "derivative_free": bool(derivative_free),
            "n_max": int(n_max),
        },
    )
    if "params" not in r:
        r["params"] = dict(r["best"][0]["params"])
    return r


class Measured:
    """A MERL measured table (``.binary``: 90 × 90 × 180 entries per channel, red, green, blue), from
    :func:`load_measured` or :meth:`Kernel.tabulate`. :func:`fit` fits formulas to it; :func:`compare` and
    :func:`plot` take it beside formulas (a table saved to or read from a file)."""

    __slots__ = ("_native",)

    #: Entries per channel (90 · 90 · 180).
    entries: int = 90 * 90 * 180
    #: Red, green, blue.
    channels: int = 3

    def __init__(self, *_: Any, **__: Any) -> None:
        raise TypeError("use lobe.load_measured(path) or Kernel.tabulate() to make a Measured")

    @classmethod
    def _from_native(cls, native: Any) -> "Measured":
        m = object.__new__(cls)
        m._native = native
        return m

    @property
    def name(self) -> str:
        """The file it was read from, or the formula it tabulates."""
        return self._native.name

    @property
    def path(self) -> Optional[str]:
        """The file it was read from or saved to (None for a table only in memory)."""
        return self._native.path

    @property
    def measured_entries(self) -> int:
        """Entries measured in every channel (a tabulated table leaves out those below the horizon)."""
        return self._native.measured_entries

    def values(self, wi: Any, wo: Any, *, lookup: str = "linear") -> np.ndarray:
        """The table's values (red, green, blue: shape ``(..., 3)``) for incident ``wi`` (the formula's L) and
        outgoing ``wo`` (V), arrays of shape ``(..., 3)`` in the local frame (N = +z) broadcast together:
        lobe's lookup, ``"linear"`` (multilinear between entries, the default) or ``"nearest"`` (MERL's
        reference code), as ``--lookup``; 0 below either horizon (docs/measured.md)."""
        a, b = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
        if a.ndim == 0 or b.ndim == 0 or a.shape[-1] != 3 or b.shape[-1] != 3:
            raise _error(f"wi and wo must have shape (..., 3), not {a.shape} and {b.shape}", "directions are x, y, z in the local frame (N = +z)")
        try:
            shape = np.broadcast_shapes(a.shape[:-1], b.shape[:-1])
        except ValueError:
            raise _error(f"wi of shape {a.shape} and wo of shape {b.shape} do not broadcast") from None
        out = self._native.values(_flat(a, shape, (3,)), _flat(b, shape, (3,)), str(lookup))
        return out.reshape(shape + (3,))

    def to_bytes(self) -> bytes:
        """The MERL file's bytes."""
        return self._native.to_bytes()

    def save(self, path: Union[str, "os.PathLike[str]"]) -> "Measured":
        """Write the table as a MERL ``.binary`` file; returns the table with its new :attr:`path`."""
        p = os.fspath(path)
        if not p.lower().endswith(".binary"):
            raise _error(f"`{p}`: a MERL table is named .binary", "e.g. save('gold.binary')")
        with open(p, "wb") as f:
            f.write(self.to_bytes())
        return Measured._from_native(self._native.saved_as(p))

    def __repr__(self) -> str:
        return f"<lobe.Measured {self.name!r}: {self.measured_entries} of {self.entries} entries measured>"


def load_measured(path: Union[str, "os.PathLike[str]"]) -> Measured:
    """Read a MERL ``.binary`` table (its size, header and values checked, as the command line reads it)."""
    return Measured._from_native(_lobe.load_measured(os.fspath(path)))


def _image(rgb: bytes, w: int, h: int) -> Image:
    return np.frombuffer(rgb, dtype=np.uint8).reshape(h, w, 3).copy().view(Image)


def _baked_set(items: Sequence[Any], params: Mapping[str, float]) -> List[Tuple[str, float]]:
    """``params`` and the kernels' baked values as one ``--set`` list (a name baked at two values, or baked
    and given, is an error)."""
    out = {}
    for k, v in params.items():
        _not_none(k, v)
        out[k] = float(v)
    for it in items:
        if isinstance(it, Kernel):
            for k, v in it.baked.items():
                if k in out and out[k] != v:
                    raise _error(f"`{k}` is {out[k]} and baked at {v} in {it.name}", "compile the formulas without baking it, and give it once")
                out[k] = v
    return list(out.items())


def _side(x: Any, what: str) -> Tuple[str, str]:
    """A comparison's side: a kernel's file and text, or a saved table's path."""
    if isinstance(x, Kernel):
        return (x.file, x.source)
    if isinstance(x, Measured):
        if x.path is None:
            raise _error(f"{what}: the table is not saved to a file", "save it first: table = table.save('t.binary')")
        return (x.path, "")
    raise TypeError(f"{what} must be a lobe.Kernel or a lobe.Measured, not {type(x).__name__}")


def compare(
    a: Union[Kernel, Measured],
    b: Union[Kernel, Measured],
    *,
    scene: Union[None, str, "os.PathLike[str]"] = None,
    size: Union[None, int, Tuple[int, int]] = None,
    threads: int = 0,
    srgb: bool = False,
    math: str = "precise",
    backend: str = "jit",
    **params: float,
) -> Dict[str, Any]:
    """Render a scene (default: the papers' sphere) with every material's formula replaced by ``a``, then by
    ``b`` (kernels, or measured tables saved to a file), and compare the images: ``lobe compare A B``.

    ``params`` (and the kernels' baked values) go to both formulas, each taking those it declares (``--set``);
    ``size`` is N or (width, height); ``threads``, ``srgb``, ``math`` and ``backend`` are the command's flags.
    Returns the command's ``--json`` dict (``manhattan``, ``manhattan_covered``, ``max_gray_diff``, ``rmse``,
    ``psnr``, ``width``, ``height``, ``nan``, …; its ``a`` and ``b``, the files, as ``a_name`` and ``b_name``)
    with the images as :class:`Image`: ``"a"``, ``"b"``,
    ``"difference"`` (the |Δgray| heat map, white at ``max(max_gray_diff, 1)``) and ``"figure"`` (A | B | heat
    map with headings and colour bar: the picture ``-o`` writes)."""
    if isinstance(size, int):
        size = (size, size)
    wh = None if size is None else (int(size[0]), int(size[1]))
    sa, sb = _side(a, "a"), _side(b, "b")
    ia, ib, diff, fig, r = _lobe.compare(sa, sb, None if scene is None else os.fspath(scene), wh, _baked_set([a, b], params), int(threads), bool(srgb), str(math), str(backend))
    # The command's "a" and "b" name the files; here they are the images, the names "a_name" and "b_name".
    r["a_name"], r["b_name"] = r.pop("a"), r.pop("b")
    r.update(a=_image(*ia), b=_image(*ib), difference=_image(*diff), figure=_image(*fig))
    return r


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
    """Plot lobes as ``lobe plot`` does: the kernels' formulas at ``params`` and their baked values (each takes
    those it declares), then the measured tables (one curve per channel), then ``reference`` (or, with
    ``error=True``, each curve minus it). Value against the angle from the lobe axis, or with ``incidence``
    (degrees from the normal) against the signed view angle in the plane of incidence; ``polar``, ``log``,
    ``ylim=(lo, hi)``, ``size=(width, height)`` and ``lookup`` are the command's flags.

    Returns the picture (an :class:`Image`) and the plotted numbers: ``{"title", "x_label", "y_label" (the axes'
    meanings), "x": array (every curve shares it), "y": {legend name: array}}``."""
    kernels = [k for k in items if isinstance(k, Kernel)]
    tables = []
    for t in items:
        if isinstance(t, Measured):
            tables.append((t.path or t.name, t._native))
        elif not isinstance(t, Kernel):
            raise TypeError(f"plot() takes lobe.Kernel and lobe.Measured items, not {type(t).__name__}")
    if reference is not None and not isinstance(reference, Kernel):
        raise TypeError("reference must be a lobe.Kernel")
    if not items:
        raise _error("nothing to plot", "give kernels or measured tables: lobe.plot(k1, k2, n=50)")
    lim = None
    if ylim is not None:
        y = tuple(ylim)
        if len(y) != 2:
            raise _error(f"ylim takes two values, lo and hi, not {ylim!r}", "e.g. ylim=(0, 2)")
        lim = (float(y[0]), float(y[1]))
    w, h = (int(size), int(size)) if isinstance(size, int) else (int(size[0]), int(size[1]))
    sets = _baked_set(kernels + ([reference] if reference is not None else []), params)
    (rgb, pw, ph), title, x, y, series = _lobe.plot(
        [k._native for k in kernels], tables, None if reference is None else reference._native, bool(error), sets,
        None if incidence is None else float(incidence), str(lookup), bool(polar), bool(log), lim, (w, h),
    )
    data: Dict[str, Any] = {"title": title, "x_label": x, "y_label": y, "x": np.array(series[0][1]) if series else np.empty(0), "y": {n: np.array(ys) for n, _, ys in series}}
    return _image(rgb, pw, ph), data
