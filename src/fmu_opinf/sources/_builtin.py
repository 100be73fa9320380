"""The reference Python simulator as a snapshot source."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InputSpecError
from ._base import Source

__all__ = ["BuiltinSource", "BUILTIN_SYSTEMS"]

#: Names accepted by :class:`BuiltinSource` (and ``builtin:NAME`` in :func:`open_source`).
BUILTIN_SYSTEMS = ("anchored-msd", "triple-chain")


class BuiltinSource(Source):
    """The reference Python simulator (:mod:`fmu_opinf.newmark`) on a benchmark system.

    Parameters
    ----------
    name : {"anchored-msd", "triple-chain"}
        Benchmark system (spec sections 1-2).
    **size_options
        Passed to the system factory: ``g`` for ``anchored-msd``; ``n1, alpha, beta, v`` for
        ``triple-chain``.
    """

    kind = "builtin"

    def __init__(self, name: str, **size_options: Any) -> None:
        from .. import systems

        if name not in BUILTIN_SYSTEMS:
            raise InputSpecError(f"unknown builtin system {name!r}; choose one of {', '.join(BUILTIN_SYSTEMS)}")
        try:
            self.system = systems.builtin_system(name, **size_options)
        except TypeError as exc:
            raise InputSpecError(f"bad option for builtin:{name}: {exc}") from None
        self.name = name
        self.options = dict(size_options)
        sysm = self.system
        n, m, p = sysm.n, sysm.m, sysm.p
        self.position_names = [f"x[{i}]" for i in range(1, n + 1)]
        self.velocity_names = [f"v[{i}]" for i in range(1, n + 1)]
        self.acceleration_names = [f"a[{i}]" for i in range(1, n + 1)]
        self.input_names = ["u"] if m == 1 else [f"u[{j}]" for j in range(1, m + 1)]
        self.output_names = [f"y[{j}]" for j in range(1, p + 1)]
        self.constraint = sysm.constraint if sysm.constraint else "none"
        self._stepper: Any = None

    def provenance(self) -> dict[str, Any]:
        return {
            "source_kind": "builtin",
            "source": f"builtin:{self.name}",
            "model_name": getattr(self.system, "name", self.name),
            "system_options": dict(self.options),
        }

    def recipe(self) -> tuple[type, dict[str, Any]]:
        return BuiltinSource, {"name": self.name, **self.options}

    def start(self, t: np.ndarray, U: np.ndarray) -> None:
        from ..newmark import NewmarkStepper

        self._plan(t, U)
        steps = np.diff(self._t)
        h = float(steps[0])
        if not np.allclose(steps, h, rtol=1e-9, atol=0.0):
            raise InputSpecError("the builtin source needs a uniform time grid")
        sysm = self.system
        self._stepper = NewmarkStepper(sysm.M, sysm.D, sysm.K, sysm.B, h, G=sysm.G, constraint=sysm.constraint)
        self._stepper.start(self._U[0], t0=float(self._t[0]))

    def read(self, out: np.ndarray) -> None:
        st, n, p = self._stepper, self.n, self.p
        out[:n] = st.x
        out[n:2 * n] = st.v
        out[2 * n:3 * n] = st.a
        out[3 * n:3 * n + p] = self.system.output(st.x, st.v)

    def step(self, t: float, h: float, u: np.ndarray) -> None:
        if abs(h - self._stepper.h) > 1e-12 * abs(h):
            self._stepper.set_step(h)
        self._stepper.step(u)

    def close(self) -> None:
        self._stepper = None
