"""Register reference generator: renders docs/registers.md from the register declarations.

    python -m robot_firmware.fpga.regdoc            # rewrite docs/registers.md
    python -m robot_firmware.fpga.regdoc --check    # exit 1 if it is stale

The reference is rendered from a default `Fabric`, so it shows the address map and
reset values of the default configuration.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from robot_firmware.fpga.address_map import BRIDGE_BASE, BRIDGE_SPAN_BYTES
from robot_firmware.fpga.fabric import Fabric
from robot_firmware.fpga.faults import FAULT_EFFECTS
from robot_firmware.fpga.registers import Access, Peripheral, Register

DEFAULT_PATH = Path(__file__).resolve().parents[2] / "docs" / "registers.md"
REGENERATE_COMMAND = "python -m robot_firmware.fpga.regdoc"


def render_markdown(fabric: Fabric | None = None) -> str:
    """The register reference of `fabric` (default configuration if None) as markdown."""
    fabric = fabric if fabric is not None else Fabric()
    mapped = fabric.bus.mapped()
    lines = [
        "# FPGA register reference",
        "",
        f"<!-- Generated from robot_firmware/fpga by `{REGENERATE_COMMAND}`; do not edit. -->",
        "",
        f"The IPs sit behind the lightweight HPS-to-FPGA bridge at `{_hex(BRIDGE_BASE)}` "
        f"({BRIDGE_SPAN_BYTES // 1024 // 1024} MiB); each instance owns a "
        f"`0x{fabric.bus.window_bytes:X}`-byte window. Shown for the default configuration "
        f"({len(fabric.sonar)} sonars).",
        "",
        "* Every register is 32 bits wide; access it with aligned 32-bit reads and writes.",
        "* Bits outside the listed fields are reserved: they read as 0 and writes to them "
        "are ignored.",
        "* A refused access (unmapped or misaligned address, write to RO/RC, read of WO, "
        "value outside 32 bits) is a bus error: it changes nothing, is counted per kind, "
        "and the bus returns an error result instead of a value.",
        "* Values marked signed are 32-bit two's complement.",
        "",
        "## Access kinds",
        "",
        "| Access | Meaning |",
        "|---|---|",
        *(f"| {access.value} | {access.meaning} |" for access in Access),
        "",
        "## Address map",
        "",
        "| Base | End | Instance | Peripheral |",
        "|---|---|---|---|",
    ]
    for base, peripheral in mapped:
        end = base + fabric.bus.window_bytes - 1
        lines.append(
            f"| `{_hex(base)}` | `{_hex(end)}` | `{peripheral.name}` | {peripheral.TITLE} |"
        )
    groups: dict[type[Peripheral], list[tuple[int, Peripheral]]] = {}
    for base, peripheral in mapped:
        groups.setdefault(type(peripheral), []).append((base, peripheral))
    for instances in groups.values():
        lines.append("")
        lines.extend(_render_group(instances))
    lines.append("")
    lines.extend(_render_fault_effects())
    return "\n".join(lines) + "\n"


def _render_fault_effects() -> list[str]:
    """The register faults (robot_firmware/fpga/faults.py): where each acts, what the firmware
    sees and does."""
    lines = [
        "## Fault injection",
        "",
        "Register faults (`swarm fault`, the world's and each robot's `fault` admin verb, a "
        "scenario's `faults:` schedule) act on the hardware side of the IPs, below the "
        "firmware: the firmware meets them only in the registers it reads and the pins it "
        "drives. A fault on the same output as an active one replaces it; `clear_registers` "
        "releases all, and the IPs then behave as if never faulted; a restarted robot boots "
        "with none, as after a power cycle. A robot's `fault` verb "
        "with an empty body lists its active faults; its telemetry names them in "
        "`register_faults`.",
        "",
        "| Fault | Acts on | What the firmware sees | What the firmware does |",
        "|---|---|---|---|",
    ]
    lines.extend(
        f"| `{e.fault}` | {_cell(e.acts_on)} | {_cell(e.firmware_sees)} "
        f"| {_cell(e.firmware_does)} |"
        for e in FAULT_EFFECTS
    )
    return lines


def _render_group(instances: Sequence[tuple[int, Peripheral]]) -> list[str]:
    first_base, first = instances[0]
    names = ", ".join(f"`{p.name}` at `{_hex(base)}`" for base, p in instances)
    lines = [f"## {first.TITLE}", "", _cell(first.SUMMARY), ""]
    lines.append(f"Instances: {names}.")
    if len(instances) > 1:
        lines.append(
            f"The Address column is for `{first.name}`; "
            "for another instance add the offset to its base."
        )
    lines += [
        "",
        "| Offset | Address | Register | Access | Reset | Fields | Description |",
        "|---|---|---|---|---|---|---|",
    ]
    for reg in first.registers:
        resets = [p.register(reg.name).reset for _, p in instances]
        lines.append(
            f"| `0x{reg.offset:02X}` | `{_hex(first_base + reg.offset)}` | `{reg.name}` "
            f"| {reg.access.value} | {_reset_cell(resets, instances)} | {_fields_cell(reg)} "
            f"| {_description_cell(reg)} |"
        )
    return lines


def _reset_cell(resets: Sequence[int], instances: Sequence[tuple[int, Peripheral]]) -> str:
    if len(set(resets)) == 1:
        return _reset_value(resets[0])
    return "<br>".join(
        f"`{p.name}`: {_reset_value(value)}"
        for value, (_, p) in zip(resets, instances, strict=True)
    )


def _reset_value(value: int) -> str:
    return f"`{_hex(value)}`" if value < 10 else f"`{_hex(value)}` ({value})"


def _fields_cell(reg: Register) -> str:
    ordered = sorted(reg.fields, key=lambda f: f.lsb, reverse=True)
    return "<br>".join(f"`{f.bits}` `{f.name}`: {_cell(f.doc)}" for f in ordered)


def _description_cell(reg: Register) -> str:
    text = _cell(reg.doc)
    if reg.affects:
        text += " Writing also updates " + ", ".join(f"`{name}`" for name in reg.affects) + "."
    return text


def _hex(value: int) -> str:
    return f"0x{value:08X}"


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def write_reference(path: Path = DEFAULT_PATH) -> Path:
    """Render the reference and write it to `path`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render_markdown(), encoding="utf-8")
    return path


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Render the FPGA register reference.")
    parser.add_argument("--output", type=Path, default=DEFAULT_PATH, help="markdown file")
    parser.add_argument("--check", action="store_true", help="exit 1 if the file is stale")
    args = parser.parse_args(argv)
    output: Path = args.output
    if args.check:
        current = output.read_text(encoding="utf-8") if output.exists() else ""
        if current != render_markdown():
            print(f"{output} is stale; regenerate with: {REGENERATE_COMMAND}", file=sys.stderr)
            return 1
        return 0
    print(f"wrote {write_reference(output)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
