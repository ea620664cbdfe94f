"""Figures: one look per method everywhere (PNGs and the 3D scene), axes with units, legends that
explain.

The PNG checks read the matplotlib Figures before they are written; the scene checks read the static
Meshcat page built from test_viz's fixture solutions.
"""

from __future__ import annotations

import copy
from dataclasses import replace
import re

import numpy as np
import pytest

from surestep_ocp.method_grammar import BASE_METHODS, REPLAN_METHODS, all_names
from surestep_ocp.output.plot_styles import known, style_of, styles_of

UNIT = re.compile(r"\[[^\]]+\]")


def test_every_method_name_has_its_own_style():
    """Every name the method grammar accepts, and replan's, has a fixed style no other name
    shares."""
    names = [*all_names(), *REPLAN_METHODS]
    assert all(known(m) for m in names)
    looks = {m: (s.colour, s.marker, s.linestyle, s.filled) for m, s in styles_of(names).items()}
    assert len(set(looks.values())) == len(names)
    assert style_of("ocp-replan-3", ["ocp-replan-3", "ocp-replan-7"]) != style_of(
        "ocp-replan-7", ["ocp-replan-3", "ocp-replan-7"])


def test_registry_is_what_the_code_runs():
    """The style registry's names are the ones `run_method` parses, compare and evaluate run."""
    from surestep_ocp.model.belief import COMPONENTS
    from surestep_ocp.evaluation.evaluation import DEFAULT_METHODS
    from surestep_ocp.method_grammar import CLOSED_LOOP_METHODS
    from surestep_ocp.methods.registry import COMPARE_METHODS, parse_method

    names = all_names()
    for m in names:
        parse_method(m)
    assert len(names) == (len(BASE_METHODS) + len(CLOSED_LOOP_METHODS)) * (len(COMPONENTS) + 1) * 4
    assert set(COMPARE_METHODS) | set(DEFAULT_METHODS) <= set(names)


def test_scene_colours_are_the_png_colours():
    pytest.importorskip("meshcat")
    from surestep_ocp.viz import style

    names = [*BASE_METHODS, *REPLAN_METHODS, "ocp-no-fov", "ocp-replan-4"]
    assert style.method_colors(names) == {m: s.rgb for m, s in styles_of(names).items()}
    assert style.GOAL_COLOR != style.START_COLOR


@pytest.fixture(scope="module")
def solutions(default_setup):
    """The default problem's baseline under five method names, ocp and ocp-from-gradient
    coinciding."""
    from surestep_ocp.methods.registry import run_method

    base = run_method(default_setup, "baseline")
    out = []
    for k, m in enumerate(("baseline", "gradient", "gradient-no-pose-loss", "ocp",
                           "ocp-from-gradient")):
        bend = 0.004 * min(k, 3) * np.sin(np.linspace(0, np.pi, len(base.poses)))
        sigma = np.asarray(base.sigma) * 0.7 ** min(k, 3)
        out.append(replace(copy.deepcopy(base), method=m,
                           poses=[list(np.add(p, [b, 0, 0, 0, 0, 0]))
                                  for p, b in zip(base.poses, bend)],
                           sigma=sigma.tolist(), trace=[float(np.trace(S)) for S in sigma]))
    return out


def _data_axes(fig):
    return [ax for ax in fig.axes if ax.lines]


def _lines(ax, label):
    return [ln for ln in ax.lines if ln.get_label() == label]


def test_trace_figure_splits_position_and_orientation(solutions):
    """Two panels in m^2 and rad^2 whose sum is the solution's Tr(Sigma_t|t)."""
    from surestep_ocp.output.plots_compare import trace_figure

    fig = trace_figure(solutions)
    pos, ori = _data_axes(fig)
    assert "[m²]" in pos.get_ylabel() and "[rad²]" in ori.get_ylabel()
    for s in solutions:
        (a,), (b,) = _lines(pos, s.method), _lines(ori, s.method)
        np.testing.assert_allclose(a.get_ydata() + b.get_ydata(), s.trace, rtol=1e-9)
    assert {t.get_text() for t in pos.get_legend().get_texts()} == {s.method for s in solutions}


def test_path_figure_axes_units_markers_and_legend(solutions):
    """Labelled axes with units; start, goal, image centre and border explained; coinciding methods
    look apart."""
    from surestep_ocp.output.plots_compare import path_figure

    fig = path_figure(solutions)
    img, depth = _data_axes(fig)
    for ax in (img, depth):
        assert UNIT.search(ax.get_ylabel()), ax.get_ylabel()
        assert UNIT.search(ax.get_xlabel()) or ax.get_xlabel() == "step t"
    assert ("[px]" in img.get_xlabel() and "[px]" in img.get_ylabel()
            and "[mm]" in depth.get_ylabel())
    legend = {t.get_text() for t in img.get_legend().get_texts()}
    assert {s.method for s in solutions} | {"start", "goal", "image centre"} <= legend
    assert any(t.startswith("image border") for t in legend)
    (ocp,), (hybrid,) = _lines(img, "ocp"), _lines(img, "ocp-from-gradient")
    assert hybrid.get_zorder() > ocp.get_zorder() and hybrid.get_linewidth() < ocp.get_linewidth()
    assert hybrid.get_linestyle() != ocp.get_linestyle() and hybrid.get_marker() != ocp.get_marker()
    for s in solutions:
        (ln,) = _lines(img, s.method)
        assert (ln.get_color() == style_of(s.method).colour
                and ln.get_marker() == style_of(s.method).marker)


@pytest.fixture()
def scene_solutions(tmp_path):
    pytest.importorskip("meshcat")
    pytest.importorskip("pinocchio")
    from test_viz import ARM_URDF, make_solution  # tests/ is on sys.path under pytest

    urdf = tmp_path / "arm.urdf"
    urdf.write_text(ARM_URDF)
    return [make_solution(urdf, "baseline", 0.0, 1),
            make_solution(urdf, "gradient-no-pose-loss", 0.08, 3),
            make_solution(urdf, "ocp", 0.15, 2)]


def test_static_page_has_a_legend_entry_per_method(tmp_path, scene_solutions):
    """The page's legend names every drawn method in its colour, the start and the goal; one start
    marker."""
    from surestep_ocp.viz import write_static_html

    info = write_static_html(scene_solutions, tmp_path / "scene.html")
    html = (tmp_path / "scene.html").read_text()
    legend = html[html.index('<div id="surestep-legend"'):]
    entries = re.findall(r'data-method="([^"]+)">.*?background:(#[0-9a-f]{6})', legend)
    assert dict(entries) == {m: style_of(m).colour for m in info.paths}
    assert sorted(info.paths) == sorted(s["method"] for s in scene_solutions)
    assert "start" in legend and "goal" in legend and "ellipsoids" in legend
    assert "/meshcat/start/marker" in info.nodes
    np.testing.assert_allclose(info.start, info.paths["ocp"].points[0])


def test_paths_the_arm_does_not_follow_show_few_faint_ellipsoids(scene_solutions):
    """The baseline's (large) ellipsoids do not hide the other paths: few start visible, at lower
    opacity."""
    from surestep_ocp.viz import style
    from surestep_ocp.viz.paths import ellipsoid_opacity
    from surestep_ocp.viz.recorder import recording_visualizer
    from surestep_ocp.viz.scene import build_scene

    vis, window = recording_visualizer()
    info = build_scene(scene_solutions, vis=vis, hide_above=np.inf)
    assert info.animated == "ocp" and info.paths["ocp"].hidden == []

    def opacity(node):
        return [c for c in window.decoded[node]
                if c["type"] == "set_object"][-1]["object"]["materials"][0]["opacity"]

    for m, scale in (("ocp", 1.0), ("baseline", style.OTHER_ELLIPSOID_OPACITY),
                     ("gradient-no-pose-loss", style.OTHER_ELLIPSOID_OPACITY)):
        p = info.paths[m]
        # every one drawn, to be switched on in the controls
        assert len(p.ellipsoid_nodes) == len(p.nodes)
        for node, r in zip(p.ellipsoid_nodes, p.radii):
            assert opacity(node) == pytest.approx(scale * ellipsoid_opacity(r.max()))
        if m != "ocp":
            shown = [n for n in p.ellipsoid_nodes if n not in p.hidden]
            assert 1 <= len(shown) <= style.OTHER_ELLIPSOIDS and shown[-1] == p.ellipsoid_nodes[-1]
