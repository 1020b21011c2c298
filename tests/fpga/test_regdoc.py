"""The committed register reference matches the declarations."""

from __future__ import annotations

from pathlib import Path

from robot_firmware.fpga import Fabric
from robot_firmware.fpga.regdoc import DEFAULT_PATH, REGENERATE_COMMAND, main, render_markdown


def test_committed_register_reference_is_not_stale() -> None:
    committed = DEFAULT_PATH.read_text(encoding="utf-8") if DEFAULT_PATH.exists() else ""
    assert committed == render_markdown(), (
        f"docs/registers.md is stale; regenerate it with: {REGENERATE_COMMAND}"
    )


def test_reference_lists_every_register_of_every_peripheral() -> None:
    text = render_markdown()
    for base, peripheral in Fabric().bus.mapped():
        assert f"`{peripheral.name}`" in text
        assert f"0x{base:08X}" in text
        for reg in peripheral.registers:
            assert f"| `{reg.name}` | {reg.access.value} |" in text


def test_check_mode_reports_a_stale_file(tmp_path: Path) -> None:
    target = tmp_path / "registers.md"
    assert main(["--check", "--output", str(target)]) == 1
    assert main(["--output", str(target)]) == 0
    assert main(["--check", "--output", str(target)]) == 0
    target.write_text(target.read_text(encoding="utf-8") + "edit\n", encoding="utf-8")
    assert main(["--check", "--output", str(target)]) == 1
