"""Scenario definitions: a motor, a bench, an excitation, grids over any of them, estimators, repetitions.

A scenario is a TOML file (the built-in ones live in ``scenarios/builtin/``)::

    name = "article"
    description = "The article's four sines, with Monte Carlo spread"
    seed = 2026
    repetitions = 50
    methods = "all"                 # or a list of names from identify.available_methods()

    [motor]                         # any knob of Motor: a, b, friction, static_friction, bias, dead_zone, input_delay
    a = 25.0                        # (or structure = "two-mass", any registered structure the simulator
    b = 3.0                         # carries, with its parameters: inertia_ratio = 1.5, ...)

    [bench]                         # any knob of Encoder, SimRig or Experiment: counts_per_rev,
    sample_period = 0.005           # angle_noise, jitter, drop_rate, sample_period, duration, ...
    counts_per_rev = 16667
    duration = 10.0

    [excitation]                    # a sine (frequency rad/s, amplitude, phase rad, offset)
    frequency = 10.0                # or spec = "prbs:200,-200,10" (any motorsim excitation)
    amplitude = 200

    [grid]                          # "section.key" = [values]: the Cartesian product is swept
    "excitation.frequency" = [10, 20, 30, 40]
    "bench.angle_noise" = [0.0, 2e-4]

The keys of ``[motor]`` and ``[bench]`` are the bench knobs (:func:`motorsim.rig.bench_knobs`),
so a knob added to one of the bench's classes is a scenario key, a :class:`Setting` field and
a sweep CSV column without a change here.  ``[motor]`` also takes ``structure``, a registered model structure
(``identify.structures()``) whose plant the bench runs, and the parameters of the registered structures beyond the
Motor's knobs (a two-mass plant's ``inertia_ratio``, ``shaft_frequency``, ``shaft_damping``): a structure added to
the registry is a scenario's plant, and a grid axis over its parameters, without a change here.
Every grid point is a complete :class:`Setting`.
Unknown keys, sections or grid axes are errors that name the key.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import os
import sys
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator, Mapping

import numpy as np

from motorsim.checks import ParameterError, check_int, is_int
from motorsim.excitation import Excitation, Sine, parse_excitation
from motorsim.knobs import knobs_of
from motorsim.plant import Motor, Plant, further_parameters, named_plant
from motorsim.ranges import check_bench_values
from motorsim.rig import Experiment, SimRig, bench_knobs
from motorsim.sensors import Encoder
from motorsim.text import control_characters, printable

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

__all__ = ["Setting", "GridPoint", "Scenario", "load_scenario", "builtin_scenarios", "ScenarioError",
           "SETTING_KEYS", "DEFAULT_EXCITATION", "scenario_from_dict"]


#: Largest grid a scenario may have: every point is validated when the file is loaded.
MAX_GRID_POINTS = 100_000


class ScenarioError(ValueError):
    """A scenario file or definition breaks a rule (the message names the key)."""


#: Defaults of a scenario for the knobs the bench classes require (the article's motor).
_REQUIRED_DEFAULTS = {"a": 25.0, "b": 3.0}
#: The excitation of a scenario that gives none: the article's 200 sin(10 t).
DEFAULT_EXCITATION = "sine:10.0,200,0.0"
_SINE_KEYS = ("frequency", "amplitude", "phase", "offset")



def _structures() -> Mapping[str, Any]:
    from identify.model_structures import structures
    return structures()


#: The parameters of the registered structures beyond the Motor's knobs (``[motor]`` keys; nan where not set).
PLANT_PARAMETERS = further_parameters(_structures())
#: section -> keys a scenario may set (and sweep as ``"section.key"``): ``[motor]`` holds the
#: Motor's knobs, ``structure`` and :data:`PLANT_PARAMETERS`, ``[bench]`` every other bench knob (Encoder, SimRig,
#: Experiment).
SETTING_KEYS: dict[str, tuple[str, ...]] = {
    "motor": (*(k.name for k in knobs_of(Motor)), "structure", *PLANT_PARAMETERS),
    "bench": tuple(k.name for k in bench_knobs() if k.owner is not Motor),
    "excitation": ("spec", *_SINE_KEYS),
}
_TOP_KEYS = ("name", "description", "seed", "repetitions", "methods", "motor", "bench", "excitation", "grid")


class _SettingMethods:
    """What a :class:`Setting` builds from its knobs (the fields come from :func:`bench_knobs`)."""

    excitation: str
    structure: str

    def __post_init__(self) -> None:
        # Validate by building every object once; their messages name the parameter.
        self.sim_rig(np.random.default_rng(0) if self.needs_rng else None)
        self.experiment()

    def _knobs(self, cls: type) -> dict[str, Any]:
        return {k.name: getattr(self, k.name) for k in knobs_of(cls)}

    @property
    def needs_rng(self) -> bool:
        """True when runs differ (noise, jitter or drops), so repetitions are Monte Carlo draws."""
        knobs = {**self._knobs(Encoder), **self._knobs(SimRig)}
        return knobs["angle_noise"] > 0 or knobs["jitter"] > 0 or knobs["drop_rate"] > 0

    def motor(self) -> Plant:
        """The plant: the Motor of the motor's knobs, or the plant of the structure ``structure`` names (the knobs
        set away from their defaults and the parameters set given to it: one it does not have is refused)."""
        given = {k.name: getattr(self, k.name) for k in knobs_of(Motor)
                 if k.name in ("a", "b", "input_delay") or getattr(self, k.name) != k.default}
        given.update((n, getattr(self, n)) for n in PLANT_PARAMETERS if not math.isnan(getattr(self, n)))
        return named_plant(self.structure, given, _structures())

    def encoder(self) -> Encoder:
        """The encoder."""
        return Encoder(**self._knobs(Encoder))

    def excitation_object(self) -> Excitation:
        """The excitation."""
        return parse_excitation(self.excitation)

    def experiment(self) -> Experiment:
        """The :class:`~motorsim.rig.Experiment` every repetition runs."""
        return Experiment(self.excitation_object(), **self._knobs(Experiment))

    def sim_rig(self, rng: np.random.Generator | None) -> SimRig:
        """The simulated bench of this setting with the generator ``rng``."""
        return SimRig(self.motor(), self.encoder(), **self._knobs(SimRig), rng=rng)

    @property
    def frequency(self) -> float:
        """Frequency in rad/s of a single sine, else nan."""
        freqs: tuple[float, ...] = tuple(getattr(self.excitation_object(), "frequencies", ()))
        return float(freqs[0]) if len(freqs) == 1 else math.nan

    @property
    def amplitude(self) -> float:
        """Amplitude in duty of a single sine, else nan."""
        amps: tuple[float, ...] = tuple(getattr(self.excitation_object(), "amplitudes", ()))
        return float(amps[0]) if len(amps) == 1 else math.nan

    @property
    def n_samples(self) -> int:
        """Samples per run."""
        return self.experiment().n_samples


def _setting_fields() -> list[tuple[str, type, Any]]:
    fields: list[tuple[str, type, Any]] = [
        (k.name, k.kind, dataclasses.field(default=_REQUIRED_DEFAULTS.get(k.name, k.default)))
        for k in bench_knobs()]
    fields.append(("structure", str, dataclasses.field(default="")))
    fields += [(name, float, dataclasses.field(default=math.nan)) for name in PLANT_PARAMETERS]
    fields.append(("excitation", str, dataclasses.field(default=DEFAULT_EXCITATION)))
    return fields


def _having(name: str) -> list[str]:
    return [n for n, st in _structures().items() if name in st.param_names]


def _setting_doc() -> str:
    lines = ["Everything that defines one simulated experiment (one grid point).", "",
             "Parameters", "----------"]
    for k in bench_knobs():
        default = _REQUIRED_DEFAULTS.get(k.name, k.default)
        lines += [f"{k.name} : {k.kind.__name__}", f"    {k.help}" + (f" [{k.unit}]" if k.unit else "")
                  + f" (default {default!r}; :class:`~{k.owner.__module__}.{k.owner.__name__}`)."]
    lines += ["structure : str", "    A registered model structure whose plant the bench runs (default ``\"\"``: "
              "the Motor of the motor's knobs)."]
    for name in PLANT_PARAMETERS:
        lines += [f"{name} : float", f"    A parameter of the structures {_having(name)} (default nan: not set)."]
    lines += ["excitation : str", "    The excitation in :func:`motorsim.excitation.parse_excitation` form "
              f"(default ``{DEFAULT_EXCITATION}``)."]
    return "\n".join(lines)


if TYPE_CHECKING:
    class Setting(_SettingMethods):
        """Every bench knob as an attribute, and the excitation."""

        def __init__(self, **values: Any) -> None: ...

        def __getattr__(self, name: str) -> Any: ...
else:
    Setting = dataclasses.make_dataclass("Setting", _setting_fields(), bases=(_SettingMethods,), frozen=True,
                                         namespace={"__module__": __name__})
    Setting.__doc__ = _setting_doc()


@dataclasses.dataclass(frozen=True)
class GridPoint:
    """One point of a scenario's grid.

    Attributes
    ----------
    index : int
        Position in the grid (row-major over the axes in file order); also its seed index.
    values : tuple of (str, value)
        The grid axes' values at this point, e.g. ``(("excitation.frequency", 10.0),)``.
    setting : Setting
        The complete setting.
    """

    index: int
    values: tuple
    setting: Setting


@dataclasses.dataclass(frozen=True)
class Scenario:
    """A sweep: a base setting, grid axes, the estimators, repetitions and a seed.

    Attributes
    ----------
    name, description : str
    base : Mapping of str to value
        ``"section.key" -> value`` for every key given outside the grid.
    grid : tuple of (str, tuple)
        Axes in file order, each ``("section.key", values)``.
    methods : tuple of str
        Estimator names (``identify.available_methods(open_loop=True, first_order=True)`` when the file
        says ``"all"``).
    repetitions : int
        Monte Carlo repetitions per grid point, >= 1.
    seed : int
        Root of ``numpy.random.SeedSequence``, >= 0.
    """

    name: str
    description: str
    base: Mapping
    grid: tuple
    methods: tuple
    repetitions: int
    seed: int

    @property
    def n_points(self) -> int:
        """Number of grid points."""
        return math.prod(len(v) for _, v in self.grid)

    @property
    def axes(self) -> tuple[str, ...]:
        """Grid axis names (``"section.key"``)."""
        return tuple(k for k, _ in self.grid)

    def with_repetitions(self, repetitions: int) -> "Scenario":
        """The same scenario with another number of repetitions."""
        return dataclasses.replace(self, repetitions=_check_count("repetitions", repetitions))

    def with_methods(self, methods) -> "Scenario":
        """The same scenario comparing other estimators (``"all"`` or a sequence of names)."""
        return dataclasses.replace(self, methods=_check_methods(methods))

    def points(self) -> Iterator[GridPoint]:
        """The grid points, lazily, in row-major order over the axes."""
        names = self.axes
        for i, combo in enumerate(itertools.product(*(v for _, v in self.grid))):
            values = dict(self.base)
            values.update(zip(names, combo))
            yield GridPoint(i, tuple(zip(names, combo)), _setting(values))

    def point(self, index: int) -> GridPoint:
        """The grid point at ``index`` (row-major over the axes, as :meth:`points`), without walking the grid.

        Examples
        --------
        >>> s = scenario_from_dict({"grid": {"excitation.frequency": [10, 20], "bench.angle_noise": [0, 1e-4]}})
        >>> s.point(3).values == list(s.points())[3].values
        True
        """
        index = check_int("index", index, 0, self.n_points - 1)
        rest, combo = index, []
        for _, values in reversed(self.grid):
            rest, k = divmod(rest, len(values))
            combo.append(values[k])
        at = tuple(zip(self.axes, reversed(combo)))
        return GridPoint(index, at, _setting({**self.base, **dict(at)}))

    def max_samples(self) -> int:
        """The most samples one run of any grid point has.

        A run has ``round(duration / sample_period)`` samples (:class:`motorsim.rig.Experiment`), so
        only the grid's ``bench.duration`` and ``bench.sample_period`` axes are combined (the other
        axes at their first value): a large grid is not walked for it.
        """
        timing = [i for i, (axis, _) in enumerate(self.grid) if axis in ("bench.duration", "bench.sample_period")]
        sizes = [len(values) for _, values in self.grid]
        most = 0
        for ks in itertools.product(*(range(sizes[i]) for i in timing)):
            chosen = dict(zip(timing, ks))
            index = 0
            for i, size in enumerate(sizes):
                index = index * size + chosen.get(i, 0)
            most = max(most, self.point(index).setting.n_samples)
        return most

    def total_samples(self) -> int:
        """Samples simulated by the whole sweep."""
        return sum(p.setting.n_samples for p in self.points()) * self.repetitions


def _check_count(name: str, value: Any, lo: int = 1) -> int:
    if not is_int(value) or value < lo:
        raise ScenarioError(f"{name} must be an integer >= {lo}, got {value!r}")
    return int(value)


def _check_methods(methods) -> tuple[str, ...]:
    from identify import available_methods
    if methods == "all":
        return tuple(available_methods(open_loop=True, first_order=True))
    if isinstance(methods, str) or not isinstance(methods, (list, tuple)) or not methods:
        raise ScenarioError(f"methods must be \"all\" or a non-empty list of names, got {methods!r}")
    for m in methods:
        if m not in available_methods():
            raise ScenarioError(f"methods must name estimators among {available_methods()}, got {m!r}")
    return tuple(methods)


def _setting(values: Mapping) -> Setting:
    """Build a Setting from ``"section.key" -> value``; a sine's fields become its spec."""
    kw: dict[str, Any] = {}
    sine: dict[str, Any] = {"frequency": 10.0, "amplitude": 200, "phase": 0.0, "offset": 0}
    has_sine_keys = False
    spec = None
    for key, value in values.items():
        section, _, name = key.partition(".")
        if section == "excitation":
            if name == "spec":
                spec = value
            else:
                sine[name] = value
                has_sine_keys = True
        else:
            kw[name] = value
    if spec is not None and has_sine_keys:
        raise ScenarioError("excitation must give either spec or sine fields (frequency, amplitude, phase, "
                            f"offset), not both; got spec = {spec!r} and {sorted(k for k in sine)}")
    if spec is None:
        try:
            spec = Sine(sine["frequency"], sine["amplitude"], sine["phase"], sine["offset"]).describe()
        except (TypeError, ValueError) as exc:
            raise ScenarioError(f"excitation: {exc}") from None
    kw["excitation"] = spec
    where = ", ".join(f"{k} = {v!r}" for k, v in values.items() if not k.startswith("excitation"))
    try:
        setting = Setting(**kw)
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f"{exc} (in the setting {where})") from None
    try:            # the ranges motorid simulate holds its flags to (motorsim.ranges.BENCH_RULES)
        check_bench_values({n: getattr(setting, n) for n in RANGE_KEYS}, _key)
    except ParameterError as exc:
        raise ScenarioError(f"{exc} (in the setting {where})") from None
    return setting


#: The keys held to the bench's ranges (:func:`motorsim.ranges.check_bench_values`).
RANGE_KEYS = ("sample_period", "duration", "a", "b", "duty_limit", "bias", "initial_speed", "counts_per_rev",
              "friction", "static_friction", "dead_zone", "electrical_time_constant", "angle_noise")


def _key(name: str) -> str:
    """A knob as a scenario names it, ``section.key``."""
    return next(f"{section}.{name}" for section, keys in SETTING_KEYS.items() if name in keys)


def _check_printable(data: Mapping, source: str) -> None:
    """A scenario's name is printed in tables and progress lines: one line of printable text (its description
    may run over lines)."""
    for key in ("name", "description"):
        text = data.get(key)
        if isinstance(text, str) and control_characters(text if key == "name" else text.replace("\n", " ")):
            raise ScenarioError(f"{source}: {key} must be printable text, got '{printable(text)[:80]}' (it holds "
                                f"{control_characters(text)}: a control character, line break or lone surrogate)")


def scenario_from_dict(data: Mapping, *, source: str = "<scenario>") -> Scenario:
    """Build and validate a :class:`Scenario` from parsed TOML (see the module docstring)."""
    def fail(msg):
        raise ScenarioError(f"{source}: {msg}")

    for key in data:
        if key not in _TOP_KEYS:
            fail(f"unknown key {key!r}; allowed: {list(_TOP_KEYS)}")
    base: dict = {}
    for section, keys in SETTING_KEYS.items():
        table = data.get(section, {})
        if not isinstance(table, Mapping):
            fail(f"[{section}] must be a table, got {table!r}")
        for k, v in table.items():
            if k not in keys:
                fail(f"unknown key {section}.{k}; allowed: {list(keys)}")
            base[f"{section}.{k}"] = v
    grid_table = data.get("grid", {})
    if not isinstance(grid_table, Mapping):
        fail(f"[grid] must be a table, got {grid_table!r}")
    grid = []
    for axis, values in grid_table.items():
        section, _, k = axis.partition(".")
        if k not in SETTING_KEYS.get(section, ()):
            fail(f"grid axis {axis!r} must be section.key with a key of "
                 + "; ".join(f"[{s}] {list(ks)}" for s, ks in SETTING_KEYS.items()))
        if isinstance(values, (str, bytes)) or not isinstance(values, (list, tuple)) or not values:
            fail(f"grid axis {axis!r} must be a non-empty list of values, got {values!r}")
        base.pop(axis, None)
        grid.append((axis, tuple(values)))
    try:
        methods = _check_methods(data.get("methods", "all"))
        reps = _check_count("repetitions", data.get("repetitions", 10))
        seed = _check_count("seed", data.get("seed", 0), lo=0)
    except ScenarioError as exc:
        fail(str(exc))
    _check_printable(data, source)
    scenario = Scenario(name=str(data.get("name", Path(source).stem)), description=str(data.get("description", "")),
                        base=base, grid=tuple(grid), methods=tuple(methods), repetitions=reps, seed=seed)
    try:
        _validate_points(scenario)
    except ScenarioError as exc:
        fail(str(exc))
    return scenario


def _validate_points(scenario: Scenario) -> None:
    """Every grid point now, not hours into the sweep; a grid over :data:`MAX_GRID_POINTS` is refused first."""
    if scenario.n_points > MAX_GRID_POINTS:
        raise ScenarioError(f"the grid has {scenario.n_points:,} points, over the {MAX_GRID_POINTS:,} a sweep may "
                            "have; use fewer values per axis")
    for _ in scenario.points():
        pass


def _builtin_dir():
    return resources.files("scenarios").joinpath("builtin")


def builtin_scenarios() -> dict[str, str]:
    """Built-in scenario names and their one-line descriptions."""
    out = {}
    for entry in sorted(_builtin_dir().iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".toml"):
            data = tomllib.loads(entry.read_text(encoding="utf-8"))
            out[entry.name[:-5]] = str(data.get("description", ""))
    return out


#: The largest scenario file read, in bytes (the built-in ones are under 2 kB).
MAX_SCENARIO_BYTES = 1 << 20


def load_scenario(name_or_path: str | os.PathLike) -> Scenario:
    """A built-in scenario by name (``article``, ...) or a TOML file by path."""
    text = str(name_or_path)
    builtin = _builtin_dir().joinpath(f"{text}.toml")
    if not text.endswith(".toml") and builtin.is_file():
        source, raw = f"builtin:{text}", builtin.read_text(encoding="utf-8")
    else:
        from motorsim.files import InputFileError, read_input_bytes
        path = Path(text)
        if not path.exists():
            raise ScenarioError(f"scenario must be a built-in name {sorted(builtin_scenarios())} or an existing "
                                f".toml file, got {text!r}")
        try:       # a regular file of a scenario's size: a FIFO is never waited on, a device never read
            source, raw = str(path), read_input_bytes(path, what="scenario", max_bytes=MAX_SCENARIO_BYTES).decode()
        except InputFileError as exc:
            raise ScenarioError(str(exc)) from None
        except UnicodeDecodeError as exc:
            raise ScenarioError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    try:
        data = tomllib.loads(raw)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: not valid TOML: {exc}") from None
    except RecursionError:      # the reader recurses per level of nesting
        raise ScenarioError(f"{source}: nested too deep to read; a scenario holds tables and lists a few levels "
                            "deep") from None
    return scenario_from_dict(data, source=source)
