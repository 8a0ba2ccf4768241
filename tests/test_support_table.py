"""README's "What FPPM supports" table is addon/export.py's SUPPORT table; each
message is text the exporter really logs; each panel FPPM hides as ignored
names an ignored feature of the table."""
import inspect
import re
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")

from fppm.addon import export, export_atlas, export_light_nodes, ui  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## What FPPM supports"


def render_table(rows=export.SUPPORT) -> str:
    """The README table of ``rows`` (what ``--update``-style regeneration writes)."""
    out = ["| Blender feature | FPPM | What the log says |", "|---|---|---|"]
    for feature, status, message in rows:
        said = f"`{message.strip()}`" if message else "nothing (its panel is hidden)" \
            if status == export.IGNORED else ""
        out.append(f"| {feature} | {status} | {said} |")
    return "\n".join(out)


def readme_table() -> str:
    text = (ROOT / "README.md").read_text()
    assert SECTION in text
    body = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    return "\n".join(ln for ln in body.splitlines() if ln.startswith("|"))


def test_readme_table_is_the_exporters():
    assert readme_table() == render_table()


def test_statuses_and_messages():
    src = inspect.getsource(export)      # the exporter's classes and its FEATURE_CHECKS
    src += inspect.getsource(export_atlas)
    src += inspect.getsource(export_light_nodes)
    src += (ROOT / "core" / "scene" / "nodes.py").read_text()
    for feature, status, message in export.SUPPORT:
        assert status in (export.SUPPORTED, export.APPROXIMATED, export.IGNORED), feature
        if status == export.SUPPORTED:
            assert message == "", feature
        elif status == export.APPROXIMATED:
            # Approximations are always said (the "Approximated:" line).
            assert message, feature
        if message:
            assert message in src, (feature, message)


def test_hidden_panels_name_ignored_features():
    ignored = {f for f, st, _ in export.SUPPORT if st == export.IGNORED}
    for panel, why in ui.HIDDEN.items():
        m = re.fullmatch(r"(.+): ignored", why)
        if m:
            assert m.group(1) in ignored, (panel, why)
    # Every silently ignored feature has a hidden panel (else a user could set
    # it and see no effect and no message).
    said = {re.fullmatch(r"(.+): ignored", w).group(1) for w in ui.HIDDEN.values()
            if w.endswith(": ignored")}
    silent = {f for f, st, msg in export.SUPPORT if st == export.IGNORED and not msg}
    assert silent <= said, silent - said


if __name__ == "__main__":
    print(render_table())
