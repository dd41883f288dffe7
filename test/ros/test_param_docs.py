"""docs/nodes.md's parameter tables are the nodes' descriptors; launch arguments are typed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from eit_skin.ros.param_docs import DOCS_PAGE, main, render
from eit_skin.ros.parameters import NODE_PARAMETERS, launch_arguments, launch_overrides


def test_docs_nodes_md_is_up_to_date_with_the_descriptors() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "eit_skin.ros.param_docs", "--check"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    text = DOCS_PAGE.read_text()
    for table in NODE_PARAMETERS.values():
        for name, _, description in table:
            assert f"| `{name}` |" in text and description.replace("|", "\\|") in text, name


def test_a_stale_page_is_found_and_rewritten(tmp_path: Path) -> None:
    page = tmp_path / "nodes.md"
    stale = DOCS_PAGE.read_text().replace("| `frame_timeout_s` |", "| `frame_timeout` |")
    page.write_text(stale)
    assert main(["--check", "--page", str(page)]) == 1
    assert page.read_text() == stale  # --check writes nothing
    assert main(["--page", str(page)]) == 0
    assert page.read_text() == DOCS_PAGE.read_text()


def test_every_node_needs_its_block() -> None:
    text = DOCS_PAGE.read_text().replace("<!-- parameters: eit_classifier -->", "")
    with pytest.raises(ValueError, match="eit_classifier"):
        render(text)


def test_launch_arguments_reach_the_nodes_that_have_them_typed() -> None:
    texts = {
        "diagnostics_period_s": "0.25",
        "publish_tf": "false",
        "tf_pose": "[0.1, 0, 0.2, 0, 0, 1.57]",
        "seed": "7",
        "frame_timeout_s": "",  # not given
        "scenario": "push",
    }
    driver = launch_overrides("eit_driver", texts)
    assert driver == {
        "diagnostics_period_s": 0.25,
        "publish_tf": False,
        "tf_pose": [0.1, 0.0, 0.2, 0.0, 0.0, 1.57],
        "seed": 7,
        "scenario": "push",
    }
    assert launch_overrides("eit_classifier", texts) == {"diagnostics_period_s": 0.25}
    with pytest.raises(ValueError, match="launch argument seed:='seven'"):
        launch_overrides("eit_driver", {"seed": "seven"})
    with pytest.raises(ValueError, match="publish_tf"):
        launch_overrides("eit_driver", {"publish_tf": "maybe"})
    # every parameter but the graph's own (patch_config, layer, port) is a launch argument
    everything = {name for table in NODE_PARAMETERS.values() for name, _, _ in table}
    assert set(launch_arguments()) == everything - {"patch_config", "layer", "port"}
