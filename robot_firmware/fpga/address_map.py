"""Address map of the FPGA IPs behind the lightweight HPS-to-FPGA bridge.

Every peripheral instance owns one 0x100-byte window. The layout, as offsets from
the bridge base 0xFF200000:

    0x0000  sysid          system ID, version, capabilities, scratch
    0x0100  clock          PLL and clock dividers
    0x0200  watchdog       motor watchdog
    0x0300  positioning    indoor positioning receiver
    0x0400  qep0..qep3     quadrature encoder interfaces, one per wheel (stride 0x100)
    0x0800  pwm0..pwm3     motor PWM generators, one per wheel (stride 0x100)
    0x0C00  sonar_filter   digital filter on the sonar echo widths
    0x0D00  speed_filter   digital filter on the QEP speeds
    0x1000  sonar0..       ultrasound rangers, up to 16 (stride 0x100)
"""

BRIDGE_BASE = 0xFF20_0000
BRIDGE_SPAN_BYTES = 0x20_0000
WINDOW_BYTES = 0x100

N_WHEELS = 4
DEFAULT_N_SONAR = 12
MAX_SONAR = 16

SYSID_BASE = BRIDGE_BASE + 0x0000
CLOCK_BASE = BRIDGE_BASE + 0x0100
WATCHDOG_BASE = BRIDGE_BASE + 0x0200
POSITIONING_BASE = BRIDGE_BASE + 0x0300
QEP_BASES = tuple(BRIDGE_BASE + 0x0400 + i * WINDOW_BYTES for i in range(N_WHEELS))
PWM_BASES = tuple(BRIDGE_BASE + 0x0800 + i * WINDOW_BYTES for i in range(N_WHEELS))
SONAR_FILTER_BASE = BRIDGE_BASE + 0x0C00
SPEED_FILTER_BASE = BRIDGE_BASE + 0x0D00
SONAR_BASE = BRIDGE_BASE + 0x1000


def sonar_base(index: int) -> int:
    """Base address of ultrasound ranger `index` (0-based, below MAX_SONAR)."""
    if not 0 <= index < MAX_SONAR:
        raise ValueError(f"sonar index {index} outside 0..{MAX_SONAR - 1}")
    return SONAR_BASE + index * WINDOW_BYTES
