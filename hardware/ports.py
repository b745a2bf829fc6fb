"""Opening a port by name: device paths, pyserial URLs, and motorid's own schemes.

``fake://?a=25&b=3`` starts the emulated Arduino (:mod:`hardware.fake_device`);
``avr-sim://...`` runs the real firmware in an AVR simulator (``hardware/sim``).  Both run in
simulated time, in lock-step with the host (:mod:`hardware.lockstep`: the port has a ``clock()``),
unless the URL says ``realtime=1``.
Anything else (``/dev/ttyACM0``, ``COM3``, ``loop://``, ``socket://host:port``,
``rfc2217://...``) goes to :func:`serial.serial_for_url`.
"""
from __future__ import annotations

import contextlib
from typing import Iterator

from motorsim.checks import ParameterError
from motorsim.lazy import load

from .errors import RigDisconnectedError

__all__ = ["open_port", "available_schemes", "url_keys"]

#: scheme -> "module:function"; the function is a context manager
#: ``open_X(url: str, baudrate: int, timeout: float)`` yielding an open pyserial-compatible port.
_SCHEMES = {
    "fake": "hardware.fake_device:open_fake",
    "avr-sim": "hardware.sim.launcher:open_avr_sim",
}

#: scheme -> "module:function" returning the scheme's URL query keys.
_URL_KEYS = {
    "fake": "hardware.fake_device:url_keys",
    "avr-sim": "hardware.sim.launcher:url_keys",
}


def available_schemes() -> list[str]:
    """motorid's own URL schemes (pyserial's are accepted too)."""
    return list(_SCHEMES)


def url_keys(scheme: str) -> tuple[str, ...]:
    """The query keys a motorid URL scheme accepts (bench knobs under their own names).

    Parameters
    ----------
    scheme : {"fake", "avr-sim"}
        One of :func:`available_schemes`.

    Examples
    --------
    >>> url_keys("avr-sim")[:4]
    ('a', 'b', 'friction', 'counts_per_rev')
    """
    if scheme not in _URL_KEYS:
        raise ParameterError(f"scheme must be one of {sorted(_URL_KEYS)}, got {scheme!r}")
    return load(_URL_KEYS[scheme])()


@contextlib.contextmanager
def open_port(url: str, baudrate: int, timeout: float) -> Iterator:
    """Open ``url`` as a serial port and close it afterwards.

    Parameters
    ----------
    url : str
        A device path, a pyserial URL, or ``fake://...`` / ``avr-sim://...``.
    baudrate : int
        Line rate in baud.
    timeout : float
        Read timeout of the port in s.

    Raises
    ------
    motorsim.checks.ParameterError
        A motorid scheme whose module is not available, or a URL key breaking a rule (a ``ValueError``).
    RigDisconnectedError
        The port cannot be opened.
    """
    if not isinstance(url, str) or not url:
        raise ParameterError(f"port must be a non-empty string (a device path or URL), got {url!r}")
    scheme = url.partition("://")[0] if "://" in url else ""
    if scheme in _SCHEMES:
        try:
            opener = load(_SCHEMES[scheme])
        except (ImportError, AttributeError) as exc:
            raise ParameterError(f"port scheme {scheme}:// is not available in this installation "
                                 f"({_SCHEMES[scheme]} cannot be loaded: {exc})") from None
        with contextlib.ExitStack() as stack:
            try:
                port = stack.enter_context(opener(url, baudrate, timeout))
            except (ValueError, TypeError) as exc:   # the URL's keys break a rule
                raise ParameterError(f"port {url!r}: {exc}") from exc
            yield port
        return
    import serial

    try:
        port = serial.serial_for_url(url, baudrate=baudrate, timeout=timeout)
    except ValueError as exc:   # pyserial: unknown URL scheme or bad settings
        raise ParameterError(f"port {url!r} cannot be used: {exc} (motorid's own schemes: "
                         f"{', '.join(s + '://' for s in _SCHEMES)})") from None
    except (serial.SerialException, OSError) as exc:
        raise RigDisconnectedError(f"cannot open port {url!r}: {exc}") from None
    try:
        yield port
    finally:
        port.close()
