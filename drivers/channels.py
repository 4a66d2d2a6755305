"""CAN channel names, the same in every log format.

python-can reports the first channel of a log differently per format: ``'can0'`` in a candump
``.log`` (the interface name), ``0`` in ``.asc``, ``.blf`` and ``.mf4`` (it counts from 0), ``1``
in ``.trc`` (PEAK counts from 1) and ``None`` in its ``.csv`` and ``.db`` (not recorded). Every
channel is named here as ``canN`` with N counted from 0, so a signal map's ``channel = "can0"``
and ``--can-channel can0`` mean the same bus in every format.
"""

from __future__ import annotations

import re
from functools import lru_cache

#: Formats whose channel numbers python-can reports counted from 1 (PEAK's .trc).
ONE_BASED_SUFFIXES = frozenset({".trc"})
#: An interface name ending in a number: can0, vcan1, slcan0 all name bus N of that kind.
_NUMBERED = re.compile(r"^[a-z]*can(\d+)$", re.IGNORECASE)
#: ``--can-channel`` values that switch the channel filter off.
ANY_CHANNEL = frozenset({"any", "all", "*"})


@lru_cache(maxsize=256)
def normalise_channel(channel, suffix: str = "") -> str | None:
    """``canN`` (N from 0) for a channel as python-can reports it from a log with ``suffix``.

    ``None`` stays ``None`` (the format does not record channels); a name that carries no number
    (``"chassis"``) is kept as it is.
    """
    if channel is None:
        return None
    if isinstance(channel, int) and not isinstance(channel, bool):
        return f"can{channel - 1 if suffix.lower() in ONE_BASED_SUFFIXES else channel}"
    text = str(channel).strip()
    if text.isdigit():
        n = int(text)
        return f"can{n - 1 if suffix.lower() in ONE_BASED_SUFFIXES else n}"
    m = _NUMBERED.match(text)
    return f"can{int(m.group(1))}" if m else text


def channel_option(text: str | None) -> str | None:
    """The channel a user asked for (``--can-channel`` or a map's ``channel``), normalised.

    A bare number N is ``canN`` (counted from 0, as in candump's can0); ``any`` keeps every channel.
    """
    if text is None or str(text).strip().lower() in ANY_CHANNEL:
        return None
    return normalise_channel(str(text))
