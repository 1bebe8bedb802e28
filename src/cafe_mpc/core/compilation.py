"""Kernel compilations seen while a run's clock runs.

The package's kernels are numba functions compiled on their first call with each set of argument types and
cached on disk (``cache=True``). A first run compiles them: before the clock starts (the first solve, the
warm-up) that only delays the start, but a kernel compiled after it stalls the tick or the MPC update that
called it for tenths of a second, and the robot falls back to the PD stance while the plan runs out. A
``CompileWatch`` counts such compilations (numba's ``"numba:compile"`` event, sent for a compilation from
source, not for a load from the disk cache) so that a run can report them (``compiles_during_run`` in
metrics.json) and a test can fail on one. It also lists the package's kernels that got a new compiled
version in that time, from the disk cache or compiled (``kernels_loaded_during_run``): in a process whose
kernels are all cached, a kernel first called after the clock started is loaded then (milliseconds, not
seconds), and would be compiled then by a first run.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

from numba.core import event
from numba.core.dispatcher import Dispatcher

COMPILE_EVENT = "numba:compile"
PACKAGES = ("cafe_mpc", "cafe_mpc_lab")
"""The packages whose module-level kernels ``kernel_versions`` looks at."""


def kernel_versions(packages: tuple[str, ...] = PACKAGES) -> dict[str, int]:
    """How many compiled versions (argument types) each module-level numba kernel of the imported modules
    of ``packages`` has now, by ``module.function``."""
    versions = {}
    for module_name, module in list(sys.modules.items()):
        if module is None or module_name.split(".")[0] not in packages:
            continue
        for name, value in list(vars(module).items()):
            if isinstance(value, Dispatcher) and getattr(value.py_func, "__module__", None) == module_name:
                versions[f"{module_name}.{name}"] = len(value.overloads)
    return versions


@dataclass(eq=False)
class CompileWatch(event.Listener):
    """Counts the numba compilations between ``start()`` and ``stop()`` (or inside ``with``).

    ``compiled``: ``module.function(argument types)`` of each compilation, callers and the kernels they
    compiled in turn alike; ``seconds``: wall time of the outermost compilations (nested ones are inside
    them).
    """

    compiled: list[str] = field(default_factory=list)
    seconds: float = 0.0
    loaded: list[str] = field(default_factory=list)
    """Module-level kernels of the package with a new compiled version since ``start()`` (at ``stop()``)."""
    _versions: dict[str, int] = field(default_factory=dict)
    _depth: int = 0
    _started: float = 0.0
    _active: bool = False

    def start(self) -> CompileWatch:
        if not self._active:
            self._versions = kernel_versions()
            event.register(COMPILE_EVENT, self)
            self._active = True
        return self

    def stop(self) -> CompileWatch:
        if self._active:
            event.unregister(COMPILE_EVENT, self)
            self._active = False
            self.loaded = [
                name for name, count in kernel_versions().items() if count > self._versions.get(name, 0)
            ]
        return self

    def __enter__(self) -> CompileWatch:
        return self.start()

    def __exit__(self, *exc_info) -> None:
        self.stop()

    def on_start(self, compile_event: event.Event) -> None:
        data = compile_event.data or {}
        dispatcher = data.get("dispatcher")
        function = getattr(dispatcher, "py_func", None)
        name = f"{function.__module__}.{function.__qualname__}" if function is not None else str(dispatcher)
        arguments = ", ".join(str(argument) for argument in data.get("args", ()))
        self.compiled.append(f"{name}({arguments})")
        if self._depth == 0:
            self._started = time.perf_counter()
        self._depth += 1

    def on_end(self, compile_event: event.Event) -> None:
        self._depth = max(self._depth - 1, 0)
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._started

    @property
    def count(self) -> int:
        """How many compilations were seen."""
        return len(self.compiled)

    def summary(self) -> dict:
        """``compiles_during_run``, ``compile_seconds_during_run``, the functions (``compiled_during_run``,
        each once, in the order first seen) and ``kernels_loaded_during_run``."""
        return {
            "compiles_during_run": self.count,
            "compile_seconds_during_run": self.seconds,
            "compiled_during_run": list(dict.fromkeys(self.compiled)),
            "kernels_loaded_during_run": list(self.loaded),
        }
