"""Digital filter IP: a moving average or a median over the last WINDOW samples, per channel.

One instance filters the sonar echo widths (one channel per ranger), another the QEP
speeds (one channel per wheel). The sensor IPs push each new raw sample through the
filter and publish the result next to the raw value.

Integer arithmetic, as the hardware does it: the moving average is the sum divided by
the number of samples, truncated toward zero; the median of an even count is the
lower of the two middle samples. Until a channel has WINDOW samples, the filter works
on the samples it has. Writing MODE or WINDOW, or 1 to FLUSH, empties every channel's
history. MODE 3 is reserved and behaves as bypass; WINDOW 0 acts as 1 and values
above MAX_WINDOW as MAX_WINDOW; STATUS shows the setting in effect.
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Sequence

from robot_firmware.fpga.registers import Access, Field, Peripheral, Register

MAX_WINDOW = 16


class FilterMode(enum.IntEnum):
    """Values of the MODE register."""

    BYPASS = 0
    MOVING_AVERAGE = 1
    MEDIAN = 2


def moving_average(samples: Sequence[int]) -> int:
    """Integer mean of `samples`, truncated toward zero."""
    total = sum(samples)
    quotient = abs(total) // len(samples)
    return quotient if total >= 0 else -quotient


def median(samples: Sequence[int]) -> int:
    """Lower median of `samples`."""
    ordered = sorted(samples)
    return ordered[(len(ordered) - 1) // 2]


def latest(samples: Sequence[int]) -> int:
    """The newest sample (bypass)."""
    return samples[-1]


_MODES = {mode.value: mode for mode in FilterMode}

_KERNELS = {
    FilterMode.BYPASS: latest,
    FilterMode.MOVING_AVERAGE: moving_average,
    FilterMode.MEDIAN: median,
}


class WindowFilter:
    """Per-channel sample histories and the kernel that reduces them."""

    def __init__(
        self, channels: int, mode: FilterMode = FilterMode.BYPASS, window: int = 1
    ) -> None:
        if channels < 1:
            raise ValueError("a filter needs at least one channel")
        self.mode = mode
        self.window = window
        self._histories = [deque[int](maxlen=window) for _ in range(channels)]

    @property
    def channels(self) -> int:
        return len(self._histories)

    def configure(self, mode: FilterMode, window: int) -> None:
        """Set mode and window (1..MAX_WINDOW) and empty the histories."""
        if not 1 <= window <= MAX_WINDOW:
            raise ValueError(f"window {window} outside 1..{MAX_WINDOW}")
        self.mode = mode
        self.window = window
        self._histories = [deque[int](maxlen=window) for _ in self._histories]

    def flush(self) -> None:
        for history in self._histories:
            history.clear()

    def push(self, channel: int, sample: int) -> int:
        """Add `sample` to `channel` and return the filtered value."""
        history = self._histories[channel]
        history.append(sample)
        return _KERNELS[self.mode](history)


MODE = Register(
    name="MODE",
    offset=0x00,
    access=Access.RW,
    reset=int(FilterMode.BYPASS),
    fields=(
        Field(
            name="MODE",
            msb=1,
            lsb=0,
            doc="0 bypass, 1 moving average, 2 median, 3 reserved (bypass)",
        ),
    ),
    doc="Filter kind.",
    affects=("STATUS",),
)
WINDOW = Register(
    name="WINDOW",
    offset=0x04,
    access=Access.RW,
    reset=1,
    fields=(
        Field(
            name="LENGTH",
            msb=4,
            lsb=0,
            doc=f"samples, 1..{MAX_WINDOW}; 0 acts as 1, more as {MAX_WINDOW}",
        ),
    ),
    doc="Window length.",
    affects=("STATUS",),
)
STATUS = Register(
    name="STATUS",
    offset=0x08,
    access=Access.RO,
    reset=1,
    fields=(
        Field(name="LENGTH", msb=4, lsb=0, doc="window length in effect"),
        Field(name="MODE", msb=9, lsb=8, doc="mode in effect"),
    ),
    doc="Setting in effect.",
)
STATUS_LENGTH = STATUS.field("LENGTH")
STATUS_MODE = STATUS.field("MODE")
FLUSH = Register(
    name="FLUSH",
    offset=0x0C,
    access=Access.WO,
    reset=0,
    fields=(Field(name="FLUSH", msb=0, lsb=0, doc="1 empties the history of every channel"),),
    doc="History reset.",
)
FLUSH_FLUSH = FLUSH.field("FLUSH")

REGISTERS = (MODE, WINDOW, STATUS, FLUSH)


class DigitalFilter(Peripheral):
    """Moving-average / median filter shared by a group of sensor channels."""

    TITLE = "Digital filter"
    SUMMARY = (
        "Moving average (sum / count, truncated toward zero) or lower median over the last "
        "WINDOW samples of each channel. Two instances: sonar_filter (one channel per ranger, "
        "feeds sonar FILTERED_TICKS) and speed_filter (one channel per wheel, feeds QEP "
        "SPEED_FILTERED). Changing MODE or WINDOW, or FLUSH, empties the histories."
    )

    def __init__(self, name: str, channels: int) -> None:
        super().__init__(name, REGISTERS)
        self._filter = WindowFilter(channels)
        self._write_actions = {
            MODE.offset: self._on_config,
            WINDOW.offset: self._on_config,
            FLUSH.offset: self._on_flush,
        }

    @property
    def channels(self) -> int:
        return self._filter.channels

    # -- hardware side ---------------------------------------------------------------

    def hw_filter(self, channel: int, sample: int) -> int:
        """Push a raw sample of `channel` through the filter; returns the filtered value."""
        return self._filter.push(channel, sample)

    # -- side effects ----------------------------------------------------------------

    def _on_config(self, value: int) -> None:
        del value
        mode = _MODES.get(self._get(MODE), FilterMode.BYPASS)
        window = min(max(self._get(WINDOW), 1), MAX_WINDOW)
        self._filter.configure(mode, window)
        status = STATUS_LENGTH.insert(0, window)
        self._store(STATUS, STATUS_MODE.insert(status, self._filter.mode))

    def _on_flush(self, value: int) -> None:
        if FLUSH_FLUSH.extract(value):
            self._filter.flush()
