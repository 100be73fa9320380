"""Co-simulation FMUs (FMI 2.0 and 3.0) driven step by step through their C functions."""

from __future__ import annotations

import ctypes
import os
import shutil
import weakref
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DimensionError, FMUError
from ._base import Source, StepError, check_constraint, match_names, natural_key
from ._variables import (REAL_TYPES, VariableSelection, annotated_constraint, binary_platform, read_description,
                         show_patterns)

__all__ = ["FMUSource"]


class FMUSource(Source):
    """A co-simulation FMU (FMI 2.0 or 3.0) driven step by step through its C functions.

    The model description is read and the variables resolved at construction; the binary is
    loaded only by :meth:`start`.  Per step the recorder makes three raw C calls (set inputs,
    do step, get all recorded values into one pre-allocated row).

    Parameters
    ----------
    path : str or path-like
        The ``.fmu`` file (or an extracted FMU directory).
    positions : str, optional
        Name patterns of the positions (``*`` wildcard, comma lists, brackets literal).  Default:
        ``x[*]`` if it matches, else the states whose derivative is a state (Modelica-style
        ``der(...)`` links of the model structure).  An empty string reads no states at all
        (inputs and outputs only, as :func:`fmu_opinf.compare.compare` does).
    velocities, accelerations : str, optional
        Name patterns; default: the derivatives of the positions (velocities) if the model
        structure links them, else ``v[*]`` / ``a[*]``, else derived from the data.
    inputs, outputs : str, optional
        Name patterns; default: all real variables with causality input / output.
    constraint : {"position", "velocity", "none", "unknown"}, default="unknown"
        Constraint kind, stored for the later stages (an FMU does not say).
    parameters : dict of str to float, optional
        Start values set before initialization (real or integer variables).
    """

    kind = "fmu"

    def __init__(
        self,
        path: str | os.PathLike,
        positions: str | None = None,
        velocities: str | None = None,
        accelerations: str | None = None,
        inputs: str | None = None,
        outputs: str | None = None,
        constraint: str | None = None,
        parameters: dict[str, float] | None = None,
    ) -> None:
        self.path = Path(path)
        self._options = {
            "positions": positions,
            "velocities": velocities,
            "accelerations": accelerations,
            "inputs": inputs,
            "outputs": outputs,
            "constraint": constraint,
            "parameters": dict(parameters) if parameters else None,
        }
        md = read_description(self.path)
        self.constraint = check_constraint(constraint, annotated_constraint(self.path) or "unknown")
        self._check_interface(md)
        self.md = md
        self.fmi_version = str(md.fmiVersion)
        self.model_identifier = md.coSimulation.modelIdentifier
        self._resolve(md, positions, velocities, accelerations, inputs, outputs)
        self._parameters = self._resolve_parameters(md, parameters or {})
        self._fmu: Any = None
        self._unzipdir: str | None = None
        self._sha256: str | None = None

    # -- description ------------------------------------------------------------------------
    def _check_interface(self, md: Any) -> None:
        version = str(md.fmiVersion)
        if not (version.startswith("2") or version.startswith("3")):
            raise FMUError(f"{self.path.name} is an FMI {version} fmu; fmu-opinf supports FMI 2.0 and 3.0")
        if md.coSimulation is None:
            raise FMUError(f"{self.path.name} is a model-exchange-only fmu; fmu-opinf needs co-simulation "
                           "(export the model with co-simulation enabled)")
        plat = binary_platform(version)
        binary = f"binaries/{plat}/{md.coSimulation.modelIdentifier}"
        if self.path.is_dir():
            files = [str(p.relative_to(self.path)).replace(os.sep, "/") for p in self.path.rglob("*")]
        else:
            with zipfile.ZipFile(self.path) as zf:
                files = zf.namelist()
        if not any(f.startswith(binary + ".") for f in files):
            have = sorted({f.split("/")[1] for f in files if f.startswith("binaries/") and f.count("/") >= 2})
            raise FMUError(f"{self.path.name} has no binary for this platform ({plat}; it has: "
                           f"{', '.join(have) or 'none'}); export or compile it for {plat}")

    def _resolve(self, md: Any, positions: str | None, velocities: str | None, accelerations: str | None,
                 inputs: str | None, outputs: str | None) -> None:
        sel = VariableSelection(md, self.path)
        if positions == "":  # outputs only (validation runs): no states are read
            pos, vel, acc = [], [], []
        elif positions is not None:
            pos = sel.pattern("positions", positions, required=True)
        else:
            pos = sel.pattern("positions", "x[*]", required=False) or sel.structural_positions()
            if not pos:
                raise FMUError(f"{self.path.name} has no x[*] variables and no second-order states; "
                               "pass --positions with the position variables' names")
        if pos:
            vel = self._second(sel, "velocities", velocities, pos, "v[*]")
            acc = self._second(sel, "accelerations", accelerations, vel, "a[*]") if (vel or accelerations) else []
            if not vel and accelerations is None:
                acc = []
        for what, names in (("velocities", vel), ("accelerations", acc)):
            if names and len(names) != len(pos):
                raise FMUError(f"{len(pos)} positions but {len(names)} {what} in {self.path.name}; "
                               f"give --positions/--{what} patterns that match the same number of variables")
        if acc and not vel:
            raise FMUError("accelerations without velocities are not supported; pass --velocities too")
        self.position_names, self.velocity_names, self.acceleration_names = pos, vel, acc
        if inputs is None:
            self.input_names = sorted((v.name for v in md.modelVariables
                                       if v.causality == "input" and v.type in REAL_TYPES), key=natural_key)
        else:
            self.input_names = self._inputs(sel, md, inputs)
        if outputs is None:
            self.output_names = sorted((v.name for v in md.modelVariables
                                        if v.causality == "output" and v.type in REAL_TYPES), key=natural_key)
        else:
            self.output_names = sel.pattern("outputs", outputs, required=True)
        refs = {v.name: v.valueReference for v in md.modelVariables}
        self._in_vrs = [refs[n] for n in self.input_names]
        self._out_vrs = [refs[n] for n in pos + vel + acc + self.output_names]

    @staticmethod
    def _second(sel: VariableSelection, what: str, patterns: str | None, base: list[str], default: str) -> list[str]:
        if patterns is not None:
            return sel.pattern(what, patterns, required=True)
        return sel.derivatives_of(base) or sel.pattern(what, default, required=False)

    def _inputs(self, sel: VariableSelection, md: Any, patterns: str) -> list[str]:
        names = match_names(patterns, sel.names)
        if not names:
            available = [v.name for v in md.modelVariables if v.causality == "input"]
            raise FMUError(f"input {show_patterns(patterns)} is not a real variable of {self.path.name} "
                           f"(its inputs: {', '.join(available) or 'none'}); pass --inputs with an input name")
        causal = {v.name: v.causality for v in md.modelVariables}
        bad = [n for n in names if causal[n] != "input"]
        if bad:
            raise FMUError(f"{bad[0]} has causality {causal[bad[0]]!r} in {self.path.name}, not 'input'; "
                           "pass --inputs with input variables")
        return names

    def _resolve_parameters(self, md: Any, parameters: dict[str, float]) -> list[tuple[Any, float]]:
        variables = {v.name: v for v in md.modelVariables}
        out = []
        for name, value in parameters.items():
            if name not in variables:
                raise FMUError(f"parameter {name!r} is not a variable of {self.path.name}")
            out.append((variables[name], value))
        return out

    def provenance(self) -> dict[str, Any]:
        from .._hdf5 import sha256_of

        if self._sha256 is None:
            self._sha256 = sha256_of(self.path) if self.path.is_file() else ""
        return {
            "source_kind": "fmu",
            "source": str(self.path.resolve()),
            "model_name": self.md.modelName,
            "fmu_name": self.path.name,
            "fmu_guid": self.md.guid,
            "fmu_sha256": self._sha256,
            "fmi_version": self.fmi_version,
            "fmu_generation_tool": self.md.generationTool or "",
            "fmu_parameters": {v.name: value for v, value in self._parameters},
        }

    def recipe(self) -> tuple[type, dict[str, Any]]:
        return FMUSource, {"path": str(self.path), **self._options}

    # -- loading ----------------------------------------------------------------------------
    def start(self, t: np.ndarray, U: np.ndarray) -> None:
        self._plan(t, U)
        self.close()
        self._open_binary()
        try:
            self._initialize()
        except BaseException:
            self.close()
            raise

    def _open_binary(self) -> None:
        cls, kwargs = self._fmpy_class()
        cwd = os.getcwd()
        try:
            self._fmu = cls(guid=self.md.guid, unzipDirectory=self._extracted(),
                            modelIdentifier=self.model_identifier, instanceName="fmu_opinf")
        except Exception as exc:
            raise FMUError(f"cannot load the binary of {self.path.name}: {str(exc).splitlines()[0]}") from None
        finally:
            # fmpy changes into the binary's folder to load it and stays there when loading fails; that
            # folder is deleted with the extraction, which would leave the process without a working directory
            os.chdir(cwd)
        self._log: list[str] = []
        self._bind_raw_functions()
        try:
            self._instantiate(**kwargs)
        except Exception as exc:
            self._fmu = None
            raise FMUError(f"{self.path.name} failed to instantiate ({self._last_log() or exc})") from None

    def _shared_state(self) -> dict[str, Any]:
        # unpack here, so that a copy in a child process neither unpacks again nor leaves a
        # temporary folder behind when its binary crashes
        return {"unzipdir": self._extracted()}

    def _borrow(self, state: dict[str, Any]) -> None:
        unzipdir = state.get("unzipdir")
        if unzipdir and Path(unzipdir).is_dir() and self._unzipdir is None and not self.path.is_dir():
            self._unzipdir = unzipdir  # owned (and removed) by the original

    def _extracted(self) -> str:
        """The unpacked FMU, extracted once per source object and removed with it."""
        if self.path.is_dir():
            return str(self.path)
        if self._unzipdir is None:
            from fmpy import extract

            self._unzipdir = str(extract(str(self.path)))
            weakref.finalize(self, shutil.rmtree, self._unzipdir, True)
        return self._unzipdir

    def _fmpy_class(self) -> tuple[type, dict[str, Any]]:
        if self.fmi_version.startswith("2"):
            from fmpy.fmi2 import FMU2Slave

            return FMU2Slave, {}
        from fmpy.fmi3 import FMU3Slave

        return FMU3Slave, {}

    def _bind_raw_functions(self) -> None:
        """Own prototypes of the per-step C functions taking raw addresses (no marshalling)."""
        dll = self._fmu.dll
        vp, sz = ctypes.c_void_p, ctypes.c_size_t
        if self.fmi_version.startswith("2"):
            names = ("fmi2SetReal", "fmi2GetReal", "fmi2DoStep")
            protos = ([vp, vp, sz, vp], [vp, vp, sz, vp], [vp, ctypes.c_double, ctypes.c_double, ctypes.c_int])
        else:
            names = ("fmi3SetFloat64", "fmi3GetFloat64", "fmi3DoStep")
            protos = ([vp, vp, sz, vp, sz], [vp, vp, sz, vp, sz],
                      [vp, ctypes.c_double, ctypes.c_double, ctypes.c_bool, vp, vp, vp, vp])
        funcs = []
        for name, argtypes in zip(names, protos):
            f = dll[name]  # a fresh function object: fmpy's cached one keeps its own prototype
            f.argtypes, f.restype = argtypes, ctypes.c_int
            funcs.append(f)
        self._c_set, self._c_get, self._c_step = funcs
        self._in_vr_arr = np.array(self._in_vrs, dtype=np.uint32)
        self._out_vr_arr = np.array(self._out_vrs, dtype=np.uint32)
        self._flags = np.zeros(4, dtype=np.float64)  # fmi3DoStep out-arguments (3 booleans + 1 double)

    def _logger(self, *args: Any) -> None:
        status, message = args[-3] if len(args) == 5 else args[1], args[-1]
        text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
        if status >= 2:
            self._log = (self._log + [text.strip()])[-5:]

    def _last_log(self) -> str:
        return self._log[-1] if getattr(self, "_log", None) else ""

    def _instantiate(self) -> None:
        fmu = self._fmu
        if self.fmi_version.startswith("2"):
            from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, defaultCallbacks
            from fmpy.logging import addLoggerProxy

            cb = fmi2CallbackFunctions()
            cb.logger = fmi2CallbackLoggerTYPE(
                lambda env, name, status, category, message: self._logger(env, name, status, category, message))
            cb.allocateMemory = defaultCallbacks.allocateMemory
            cb.freeMemory = defaultCallbacks.freeMemory
            addLoggerProxy(ctypes.byref(cb))
            self._callbacks = cb
            fmu.instantiate(callbacks=cb)
        else:
            fmu.instantiate(logMessage=lambda env, status, cat, msg: self._logger(env, status, msg))
        self._comp = fmu.component if isinstance(fmu.component, int) else fmu.component.value

    def _initialize(self) -> None:
        fmu, t0 = self._fmu, float(self._t[0])
        t_stop = float(self._t[-1])
        try:
            if self.fmi_version.startswith("2"):
                fmu.setupExperiment(startTime=t0, stopTime=t_stop)
                self._set_parameters()
                fmu.enterInitializationMode()
                self._set_inputs(0)
                fmu.exitInitializationMode()
            else:
                self._set_parameters()
                fmu.enterInitializationMode(startTime=t0, stopTime=t_stop)
                self._set_inputs(0)
                fmu.exitInitializationMode()
        except StepError:
            raise
        except Exception as exc:
            raise StepError(f"{self.path.name} failed to initialize at t={t0:g} ({self._last_log() or exc})",
                            0, t0) from None
        self._set_inputs(0)

    def _set_parameters(self) -> None:
        for var, value in self._parameters:
            if var.type in REAL_TYPES:
                (self._fmu.setReal if self.fmi_version.startswith("2") else self._fmu.setFloat64)(
                    [var.valueReference], [float(value)])
            elif self.fmi_version.startswith("2"):
                self._fmu.setInteger([var.valueReference], [int(value)])
            else:
                setter = getattr(self._fmu, "set" + var.type)
                setter([var.valueReference], [int(value)])

    def _set_inputs(self, i: int) -> None:
        if not self.m:
            return
        row = self._U[i]
        status = self._call_set(row.ctypes.data)
        if status > 1:
            raise StepError(self._fail_text("setting the input", i), i, float(self._t[i]))

    def _call_set(self, address: int) -> int:
        vr = self._in_vr_arr.ctypes.data
        if self.fmi_version.startswith("2"):
            return self._c_set(self._comp, vr, self.m, address)
        return self._c_set(self._comp, vr, self.m, address, self.m)

    def _fail_text(self, what: str, i: int) -> str:
        t = self._t
        when = f"t={t[i - 1]:g} -> {t[i]:g}" if i else f"t={t[0]:g}"
        log = self._last_log()
        return f"{self.path.name} returned an error {what} at step {i} ({when})" + (f": {log}" if log else "")

    # -- stepping ---------------------------------------------------------------------------
    def read(self, out: np.ndarray) -> None:
        if out.dtype != np.float64 or not out.flags.c_contiguous or out.size < len(self._out_vrs):
            raise DimensionError(f"read needs a contiguous float64 buffer of {len(self._out_vrs)} values")
        if self._get(out.ctypes.data) > 1:
            raise StepError(f"{self.path.name} returned an error reading values", -1, float("nan"))

    def _get(self, address: int) -> int:
        vr, nv = self._out_vr_arr.ctypes.data, len(self._out_vrs)
        if self.fmi_version.startswith("2"):
            return self._c_get(self._comp, vr, nv, address)
        return self._c_get(self._comp, vr, nv, address, nv)

    def step(self, t: float, h: float, u: np.ndarray) -> None:
        u = np.ascontiguousarray(u, dtype=float)
        if self.m and self._call_set(u.ctypes.data) > 1:
            raise StepError(f"{self.path.name} returned an error setting the input at t={t:g}", -1, t)
        if self._do_step(t, h) > 1:
            raise StepError(f"{self.path.name} returned an error in doStep at t={t:g}", -1, t)

    def _do_step(self, t: float, h: float) -> int:
        if self.fmi_version.startswith("2"):
            return self._c_step(self._comp, t, h, 1)
        f = self._flags.ctypes.data
        return self._c_step(self._comp, t, h, True, f, f + 1, f + 2, f + 8)

    def advance(self, rows: np.ndarray, i0: int, count: int, published: np.ndarray | None = None,
                offset: int = 0) -> None:
        if rows.dtype != np.float64 or not rows.flags.c_contiguous or rows.shape[1] != len(self._out_vrs):
            raise DimensionError(f"advance needs a C-contiguous float64 (c, {len(self._out_vrs)}) buffer")
        loop = self._advance2 if self.fmi_version.startswith("2") else self._advance3
        loop(rows, i0, count, published, offset)

    def _advance2(self, rows: np.ndarray, i0: int, count: int, published: np.ndarray | None,
                   offset: int) -> None:
        c_set, c_get, c_step, comp = self._c_set, self._c_get, self._c_step, self._comp
        in_vr, m = self._in_vr_arr.ctypes.data, self.m
        out_vr, nv = self._out_vr_arr.ctypes.data, len(self._out_vrs)
        rbase, rstride = rows.ctypes.data, rows.strides[0]
        ubase, ustride = self._U.ctypes.data, self._U.strides[0]
        t, h, changed = self._t_list, self._h_list, self._changed
        for j in range(count):
            i = i0 + j
            if i:
                if changed[i] and c_set(comp, in_vr, m, ubase + i * ustride) > 1:
                    raise StepError(self._fail_text("setting the input", i), i, t[i])
                if c_step(comp, t[i - 1], h[i], 1) > 1:
                    raise StepError(self._fail_text("in fmi2DoStep", i), i, t[i])
            if c_get(comp, out_vr, nv, rbase + j * rstride) > 1:
                raise StepError(self._fail_text("in fmi2GetReal", i), i, t[i])
            if published is not None:
                published[0] = offset + j + 1

    def _advance3(self, rows: np.ndarray, i0: int, count: int, published: np.ndarray | None,
                   offset: int) -> None:
        c_set, c_get, c_step, comp = self._c_set, self._c_get, self._c_step, self._comp
        in_vr, m = self._in_vr_arr.ctypes.data, self.m
        out_vr, nv = self._out_vr_arr.ctypes.data, len(self._out_vrs)
        rbase, rstride = rows.ctypes.data, rows.strides[0]
        ubase, ustride = self._U.ctypes.data, self._U.strides[0]
        f = self._flags.ctypes.data
        t, h, changed = self._t_list, self._h_list, self._changed
        for j in range(count):
            i = i0 + j
            if i:
                if changed[i] and c_set(comp, in_vr, m, ubase + i * ustride, m) > 1:
                    raise StepError(self._fail_text("setting the input", i), i, t[i])
                if c_step(comp, t[i - 1], h[i], True, f, f + 1, f + 2, f + 8) > 1:
                    raise StepError(self._fail_text("in fmi3DoStep", i), i, t[i])
            if c_get(comp, out_vr, nv, rbase + j * rstride, nv) > 1:
                raise StepError(self._fail_text("in fmi3GetFloat64", i), i, t[i])
            if published is not None:
                published[0] = offset + j + 1

    def _plan(self, t: np.ndarray, U: np.ndarray) -> None:
        super()._plan(t, U)
        self._t_list = self._t.tolist()
        self._h_list = [0.0] + np.diff(self._t).tolist()
        # inputs keep their values between steps: set them only when they change
        changed = np.ones(len(self._t), dtype=bool)
        if self.m:
            changed[1:] = np.any(self._U[1:] != self._U[:-1], axis=1)
        else:
            changed[:] = False
        self._changed = changed.tolist()

    def close(self) -> None:
        fmu, self._fmu = self._fmu, None
        if fmu is not None:
            try:
                fmu.terminate()
            except Exception:  # an FMU in error state may refuse; freeing is what matters
                pass
            try:
                fmu.freeInstance()
            except Exception:
                pass
