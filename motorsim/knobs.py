"""Bench knobs: the settings of the simulated bench, declared once on their dataclasses.

A *knob* is a field of :class:`~motorsim.plant.Motor`, :class:`~motorsim.sensors.Encoder`,
:class:`~motorsim.rig.SimRig` (its imperfections) or :class:`~motorsim.rig.Experiment`
that a user sets.  Each is declared with :func:`knob`, which stores its unit and help text
in the field's metadata.  Everything that lists bench settings — scenario keys, CLI flags,
sweep CSV columns, ``fake://`` URL keys, recording metadata — is derived from
:func:`knobs_of`, so adding a knob is one change: a field declared with :func:`knob`.

The knob's name is the field name everywhere: TOML key and CSV column ``name``, CLI flag
``--name`` (``_`` becomes ``-``), URL key ``name``, recording metadata ``true_name``
(for the motor's parameters) or ``name`` (for knobs declared ``recorded=True``).

For example:

>>> import dataclasses
>>> @dataclasses.dataclass(frozen=True)
... class Thing:
...     gain: float = knob(1.0, unit="1/s", help="how fast")
>>> [(k.name, k.unit, k.kind.__name__) for k in knobs_of(Thing)]
[('gain', '1/s', 'float')]
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

from .checks import ParameterError, ParameterTypeError

__all__ = ["Knob", "knob", "knobs_of", "KNOB_MAGNITUDE"]

#: The largest magnitude of a number knob given as text (a flag, a URL key): a recording's own bound.
KNOB_MAGNITUDE = 1e12

_UNIT = "motorid.unit"
_HELP = "motorid.help"
_KIND = "motorid.kind"
_RECORDED = "motorid.recorded"


@dataclasses.dataclass(frozen=True)
class Knob:
    """One bench setting.

    Attributes
    ----------
    name : str
        Field name; also the TOML key, CSV column, URL key and (``--`` + dashes) CLI flag.
    owner : type
        The dataclass that declares it (``Motor``, ``Encoder``, ``SimRig``, ``Experiment``).
    kind : type
        ``int``, ``float`` or ``bool``.
    default : object
        Default value (``dataclasses.MISSING`` when the field is required).
    unit : str
        Unit, ``""`` when dimensionless.
    help : str
        One line of help text (without the unit or default).
    recorded : bool
        True when a simulated recording's metadata carry the value (the bench's imperfections).
    """

    name: str
    owner: type
    kind: type
    default: Any
    unit: str
    help: str
    recorded: bool = False

    @property
    def flag(self) -> str:
        """The CLI flag, ``--`` + the name with dashes."""
        return "--" + self.name.replace("_", "-")

    @property
    def required(self) -> bool:
        """True when the owner has no default for this knob."""
        return self.default is dataclasses.MISSING

    def parse(self, text: str) -> Any:
        """Convert a command-line or URL string to this knob's type, naming the knob on failure."""
        try:
            if not text.isascii():
                raise ParameterError(text)      # float() would read digits of any script
            if self.kind is bool:
                low = text.strip().lower()
                if low in ("1", "true", "yes", "on"):
                    return True
                if low in ("0", "false", "no", "off"):
                    return False
                raise ParameterError(text)
            if self.kind is int:
                value = float(text)
                if not value.is_integer():
                    raise ParameterError(text)
                if abs(value) > 2**63:          # 1e308 is an integer to float(), and no count of anything
                    raise ParameterError(f"{self.name} must be an integer within +-2**63, got {text!r}")
                return int(value)
            value = float(text)
        except ValueError:
            kind = {bool: "true or false", int: "an integer", float: "a number"}[self.kind]
            raise ParameterError(f"{self.name} must be {kind}, got {text!r}") from None
        if not math.isfinite(value):
            raise ParameterError(f"{self.name} must be a finite number, got {text!r}")
        if abs(value) > KNOB_MAGNITUDE:
            raise ParameterError(f"{self.name} must be within +-{KNOB_MAGNITUDE:g} (no bench comes near it; beyond, "
                                 f"the simulation's numbers leave what a float or a count holds), got {text!r}")
        return value

    def describe(self) -> str:
        """Help text with unit and default, for ``--help`` and the docs."""
        unit = f" [{self.unit}]" if self.unit else ""
        default = "" if self.required else f" (default {self.default!r})"
        return f"{self.help}{unit}{default}"


def knob(default: Any = dataclasses.MISSING, *, unit: str, help: str, kind: type | None = None,
         recorded: bool = False) -> Any:
    """A dataclass field that is a bench knob (use in place of a plain default).

    Parameters
    ----------
    default : object, optional
        The default; omit for a required field.
    unit : str
        Unit of the value (``""`` when dimensionless).
    help : str
        One line saying what the knob does.
    kind : type, optional
        ``int``, ``float`` or ``bool``; default: the type of ``default`` (float when required).
    recorded : bool, optional
        Whether a simulated recording's metadata carry the value (default False).
    """
    if kind is None:
        kind = float if default is dataclasses.MISSING else type(default)
    if kind not in (int, float, bool):
        raise ParameterTypeError(f"kind must be int, float or bool, got {kind!r}")
    return dataclasses.field(default=default, metadata={_UNIT: unit, _HELP: help, _KIND: kind, _RECORDED: recorded})


def knobs_of(cls: type) -> tuple[Knob, ...]:
    """The knobs a dataclass declares, in field order."""
    if not dataclasses.is_dataclass(cls):
        raise ParameterTypeError(f"cls must be a dataclass, got {cls!r}")
    return tuple(Knob(f.name, cls, f.metadata[_KIND], f.default, f.metadata[_UNIT], f.metadata[_HELP],
                      f.metadata.get(_RECORDED, False))
                 for f in dataclasses.fields(cls) if _HELP in f.metadata)
