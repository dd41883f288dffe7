"""The skin designer: its server over real HTTP, and its page in a real headless Chromium.

One server and one browser for the module. Over HTTP: the shipped patches load and save back
unchanged (same text, same content hash), an edit keeps the file's comments, bad data comes
back as the loader's message, a drawing opens as a design. In the browser: the page shows the
face patch, an electrode dragged along the outline changes the map, and the saved file is what
the command line reads (same content hash) and predicts (same summary line).
"""

from __future__ import annotations

import copy
import json
import shutil
import urllib.request

import ezdxf
import pytest

from eit_skin.cli.main import main
from eit_skin.design.server import start_server
from eit_skin.design.session import DesignSession
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.accuracy_map import predict_accuracy
from eit_skin.resources import config_path
from test.support.cdp_browser import Browser, chromium_path

SHIPPED = ("arm", "face", "elbow")


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    path = tmp_path_factory.mktemp("designer")
    for name in SHIPPED:
        shutil.copy(config_path(name), path / f"{name}.yaml")
    return path


@pytest.fixture(scope="module")
def server(workdir):
    running = start_server(DesignSession.open(workdir / "face.yaml"))
    yield running
    running.stop()


def call(server, route: str, body: dict | None = None) -> dict:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(
        server.url + route.lstrip("/"), data=data, headers={"Content-Type": "application/json"}
    )
    with urllib.request.urlopen(request, timeout=120) as response:
        return json.loads(response.read())


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_patches_round_trip_unchanged(server, workdir, tmp_path, name):
    source = workdir / f"{name}.yaml"
    state = call(server, "/api/load", {"path": str(source)})
    assert state["model"]["ok"], state["model"].get("error")
    model = state["model"]
    assert model["content_hash"] == load_patch(source).content_hash
    assert model["prediction"]["line"].startswith(model["layer_names"][0])
    # what the page sends back unchanged: the data it was given
    again = call(server, "/api/update", {"data": state["data"], "layer_index": 0})
    assert again["content_hash"] == model["content_hash"]
    out = tmp_path / f"{name}_saved.yaml"
    saved = call(server, "/api/save", {"path": str(out)})
    assert saved["ok"], saved.get("error")
    assert out.read_text() == source.read_text()
    assert saved["content_hash"] == load_patch(out).content_hash == model["content_hash"]


def test_an_edit_keeps_the_comments_and_bad_data_names_the_key(server, workdir, tmp_path):
    state = call(server, "/api/load", {"path": str(workdir / "face.yaml")})
    data = copy.deepcopy(state["data"])
    electrodes = data["layers"][0]["electrodes"]
    electrodes["positions"][8] = 0.55
    electrodes["width"] = 0.006
    answer = call(server, "/api/update", {"data": data, "layer_index": 0})
    assert answer["ok"]
    assert answer["electrodes"][8]["fraction"] == pytest.approx(0.55)
    out = tmp_path / "face_edited.yaml"
    assert call(server, "/api/save", {"path": str(out)})["ok"]
    text = out.read_text()
    assert "# Face patch modelled on the seed paper" in text
    assert "contact_impedance: 2.5   # ohm*m: ~500 ohm contact resistance x 5 mm" in text
    edited = load_patch(out).layers[0]
    assert edited.electrodes[8].center_m / edited.perimeter_m == pytest.approx(0.55)
    assert edited.electrodes[0].width_m == 0.006
    bad = copy.deepcopy(data)
    bad["layers"][0]["electrodes"]["positions"][9] = 0.549  # overlaps electrode 8
    refused = call(server, "/api/update", {"data": bad, "layer_index": 0})
    assert not refused["ok"]
    assert "layers[0].electrodes" in refused["error"]


def test_a_drawing_opens_as_a_design(server, tmp_path):
    doc = ezdxf.new(units=4)
    doc.modelspace().add_circle((0, 0), 40)
    doc.modelspace().add_circle((10, 5), 6)
    doc.saveas(tmp_path / "disc.dxf")
    state = call(server, "/api/load", {"path": str(tmp_path / "disc.dxf")})
    assert state["path"] is None
    model = state["model"]
    assert model["ok"], model.get("error")
    assert len(model["electrodes"]) == 16 and len(model["holes"]) == 1
    refused = call(server, "/api/save", {"path": ""})
    assert not refused["ok"] and "give a path" in refused["error"]


@pytest.fixture(scope="module")
def browser():
    executable = chromium_path()
    if executable is None:
        pytest.skip("no chromium: `make setup` installs the Debian package as root with apt-get")
    opened = Browser(executable)
    yield opened
    opened.close()


def test_drag_an_electrode_in_the_browser_then_save(server, browser, workdir, tmp_path, capsys):
    call(server, "/api/load", {"path": str(workdir / "face.yaml")})
    browser.goto(server.url)
    browser.wait_for("window.designer && window.designer.version >= 1")
    before = browser.evaluate(
        "({map: document.getElementById('map').getAttribute('href'),"
        " summary: document.getElementById('summary').textContent,"
        " version: window.designer.version,"
        " fraction: window.designer.model.electrodes[8].fraction})"
    )
    box = browser.evaluate(
        "(() => { const b = document.querySelector('rect.electrode[data-index=\"8\"]')"
        ".getBoundingClientRect(); return [b.x + b.width / 2, b.y + b.height / 2]; })()"
    )
    # to the outline point 6 % of the perimeter further on, through two moves
    goal = browser.evaluate(
        "(() => { const d = window.designer, v = d.view, r = document.getElementById('sheet')"
        ".getBoundingClientRect(); const p = pointAt(d.model.outline,"
        f" {before['fraction']} + 0.06); return [r.left + v.px(p[0]), r.top + v.py(p[1])]; }})()"
    )
    browser.mouse("mousePressed", *box)
    browser.mouse("mouseMoved", (box[0] + goal[0]) / 2, (box[1] + goal[1]) / 2)
    browser.mouse("mouseMoved", *goal)
    browser.mouse("mouseReleased", *goal)
    browser.wait_for(f"window.designer.version > {before['version']}")
    after = browser.evaluate(
        "({map: document.getElementById('map').getAttribute('href'),"
        " summary: document.getElementById('summary').textContent,"
        " status: document.getElementById('status').textContent,"
        " error: document.getElementById('error').textContent,"
        " fraction: window.designer.model.electrodes[8].fraction})"
    )
    assert after["error"] == ""
    assert after["fraction"] == pytest.approx(before["fraction"] + 0.06, abs=0.005)
    assert after["map"] != before["map"] and after["summary"] != before["summary"]
    assert after["status"].startswith("model took ")
    out = tmp_path / "face_dragged.yaml"
    browser.evaluate(f"document.getElementById('save-path').value = {json.dumps(str(out))}")
    browser.evaluate("document.getElementById('save').click()")
    saved = browser.wait_for("window.designer.lastSave")
    assert saved["ok"], saved.get("error")
    # the command line reads the saved file to the page's content hash ...
    assert main(["patch", str(out)]) == 0
    assert f"content hash: {saved['content_hash'][:16]}" in capsys.readouterr().out
    assert browser.evaluate("window.designer.model.content_hash") == saved["content_hash"]
    # ... and predicts from it the map summary the page shows
    layer = load_patch(out).layers[0]
    assert predict_accuracy(layer, quality="preview", cache_dir=None).line() == after["summary"]
    assert "# Face patch modelled on the seed paper" in out.read_text()


def test_design_command_prints_its_local_address_and_stops_on_ctrl_c(workdir):
    import queue
    import re
    import signal
    import subprocess
    import sys
    import threading

    from test.support.patience import EVENT_S

    command = ["-m", "eit_skin.cli.main", "design", str(workdir / "elbow.yaml"), "--no-browser"]
    proc = subprocess.Popen(
        [sys.executable, *command],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # SIGINT as a terminal gives it, even when this run inherited it ignored (a
        # non-interactive shell's background command): else the Ctrl-C below is lost
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: lines.put(proc.stdout.readline()), daemon=True).start()
    try:
        line = lines.get(timeout=EVENT_S)
        match = re.search(r"at (http://127\.0\.0\.1:(\d+)/) \(Ctrl-C stops\)", line)
        assert match, line
        assert int(match.group(2)) > 0
        with urllib.request.urlopen(match.group(1), timeout=60) as page:
            assert b"eit_skin designer" in page.read()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=EVENT_S) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_add_remove_electrodes_and_holes_in_the_browser(server, browser, workdir):
    call(server, "/api/load", {"path": str(workdir / "elbow.yaml")})
    browser.goto(server.url)
    version = browser.wait_for("window.designer && window.designer.version")
    count = browser.evaluate("window.designer.model.electrodes.length")

    def click(expression: str) -> int:
        nonlocal version
        browser.evaluate(expression)
        version = browser.wait_for(
            f"window.designer.version > {version} && window.designer.version"
        )
        assert browser.evaluate("document.getElementById('error').textContent") == ""
        return version

    click("document.getElementById('add-electrode').click()")
    assert browser.evaluate("window.designer.model.electrodes.length") == count + 1
    # select electrode 2 with a press and release in place, then remove it
    centre = browser.evaluate(
        "(() => { const b = document.querySelector('rect.electrode[data-index=\"2\"]')"
        ".getBoundingClientRect(); return [b.x + b.width / 2, b.y + b.height / 2]; })()"
    )
    browser.mouse("mousePressed", *centre)
    browser.mouse("mouseReleased", *centre)
    assert browser.evaluate("window.designer.selected") == 2
    click("document.getElementById('remove-electrode').click()")
    assert browser.evaluate("window.designer.model.electrodes.length") == count
    # a 4 mm hole where the sheet's middle is drawn
    middle = browser.evaluate(
        "(() => { const d = window.designer, v = d.view, r = document.getElementById('sheet')"
        ".getBoundingClientRect(), o = d.model.outline; let x = 0, y = 0;"
        " for (const p of o) { x += p[0]; y += p[1]; }"
        " return [r.left + v.px(x / o.length), r.top + v.py(y / o.length)]; })()"
    )
    holes = browser.evaluate("window.designer.model.holes.length")
    browser.evaluate("document.getElementById('hole-mode').checked = true")
    browser.evaluate("document.getElementById('hole-diameter').value = 4")
    browser.mouse("mousePressed", *middle)
    browser.mouse("mouseReleased", *middle)
    version = browser.wait_for(f"window.designer.version > {version} && window.designer.version")
    assert browser.evaluate("window.designer.model.holes.length") == holes + 1
    radius = browser.evaluate("window.designer.data.layers[0].holes.slice(-1)[0].radius")
    assert radius == pytest.approx(0.002)
    browser.evaluate("document.getElementById('hole-mode').checked = false")
    triangles = browser.evaluate("window.designer.model.mesh.n_triangles")
    click(
        "(() => { const e = document.getElementById('max-edge'); e.value = 2.5;"
        " e.dispatchEvent(new Event('change')); })()"
    )
    assert browser.evaluate("window.designer.model.mesh.n_triangles") > triangles
