"""Dock-sim's runs one by one: variants (method × planner), which way a path moved, its speed, the phases of its
log, the executed case against the start region, and the runs worth a figure of their own.

A run's ``path`` is the true (x, y, heading) in the dock frame; the robot reverses where it moved opposite to its
heading. Top views draw a dock-frame point (x, y) at (-y, x), as report.dock_cases does.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.axes import Axes
from matplotlib.patches import FancyArrowPatch

from monodock.dock.planner import CASES
from monodock.evaluation.dock_results import TrialResult
from monodock.evaluation.dock_sim import DockSimConfig

__all__ = [
    "PATH_DT",
    "REVERSE_COLOUR",
    "STATE_COLOURS",
    "Phase",
    "Variant",
    "agreement_table",
    "draw_path",
    "executed_case_table",
    "nearest_index",
    "path_times",
    "phases",
    "reverse_mask",
    "run_file",
    "select_runs",
    "signed_speeds",
    "state_colour",
    "variant_label",
    "variant_of",
    "variants",
]

PATH_DT = 0.2  # dock-sim's path sampling, s: the times of a path without path_t
REVERSE_COLOUR = "tab:purple"
# The mission's states, one colour each (a state this list does not know gets one of the spare colours).
STATE_COLOURS = {
    "acquire": "#9e9e9e",
    "center": "#80deea",
    "calculate": "#fff176",
    "moving1-turn": "#ffcc80",
    "moving1-drive": "#ff9800",
    "moving1-back": "#ce93d8",
    "moving2": "#a5d6a7",
    "moving3": "#43a047",
    "settle": "#1565c0",
    "back-off": "#8e24aa",
    "docked": "#2e7d32",
    "failed": "#e53935",
}
_SPARE_COLOURS = ("#f48fb1", "#bcaaa4", "#b0bec5", "#c5e1a5", "#ffab91", "#9fa8da", "#ffe082", "#80cbc4")

Variant = tuple[str, str]  # (method, planner), the planner followed by the fault when the run had one


def _planner_and_fault(planner: str, fault: str) -> str:
    return planner if fault == "none" else f"{planner}, {fault}"


def variant_of(r: TrialResult) -> Variant:
    return r.method, _planner_and_fault(r.planner, r.fault)


def variants(results: Sequence[TrialResult], config: DockSimConfig | None = None) -> list[Variant]:
    """The (method, planner) pairs: the config's, method by method and planner by planner, then any other that a
    result has."""
    out: list[Variant] = []
    if config is not None:
        out = [
            (m, _planner_and_fault(p, f))
            for f in config.fault_kinds
            for m in config.methods
            for p in config.planner_kinds
        ]
    for r in results:
        if variant_of(r) not in out:
            out.append(variant_of(r))
    return out


def variant_label(variant: Variant, planners: Sequence[str]) -> str:
    """ "fused · monodock"; the method alone when only one planner ran."""
    method, planner = variant
    return method if len(set(planners)) <= 1 else f"{method} · {planner}"


def state_colour(state: str) -> str:
    if state in STATE_COLOURS:
        return STATE_COLOURS[state]
    return _SPARE_COLOURS[sum(map(ord, state)) % len(_SPARE_COLOURS)]


# --- a path's motion ------------------------------------------------------------------------------------


def path_times(r: TrialResult) -> np.ndarray:
    """The time of each path sample, s: ``path_t``, or (old results) every PATH_DT with the last at the run's end."""
    n = len(r.path)
    if len(r.path_t) == n:
        return np.asarray(r.path_t, dtype=float)
    t = np.arange(n, dtype=float) * PATH_DT
    if n >= 2 and r.time_s > t[-2]:
        t[-1] = r.time_s  # the last entry is the final pose, taken when the run ended
    return t


def _forward_steps(path: Sequence[tuple[float, float, float]]) -> np.ndarray:
    """Each step's displacement along the robot's heading (the mean of its two ends'), m; n-1 of them."""
    p = np.asarray(path, dtype=float).reshape(-1, 3)
    if len(p) < 2:
        return np.zeros(0)
    d = np.diff(p[:, :2], axis=0)
    dh = np.angle(np.exp(1j * np.diff(p[:, 2])))
    h = p[:-1, 2] + dh / 2
    return np.asarray(d[:, 0] * np.cos(h) + d[:, 1] * np.sin(h))


def reverse_mask(path: Sequence[tuple[float, float, float]], min_step: float = 0.002) -> np.ndarray:
    """Per path sample: True where the robot got there by moving backwards (opposite to its heading by more than
    ``min_step`` metres since the previous sample); the first sample is never marked. Turns on the spot are not."""
    fwd = _forward_steps(path)
    return np.concatenate([np.zeros(min(len(path), 1), dtype=bool), fwd < -min_step])


def signed_speeds(r: TrialResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(starts, ends, speeds): each step between consecutive samples, its times (s) and the speed along the
    heading over it (m/s, negative when reversing); steps of no time are left out."""
    t = path_times(r)
    fwd = _forward_steps(r.path)
    dt = np.diff(t)
    ok = dt > 1e-9
    return t[:-1][ok], t[1:][ok], fwd[ok] / dt[ok]


@dataclass(frozen=True)
class Phase:
    """One state of the mission's log: its name, when it began and ended (s), and its note."""

    state: str
    start: float
    end: float
    note: str


def phases(r: TrialResult) -> list[Phase]:
    """The log as consecutive phases; the last ends with the run (its time, or the path's last sample)."""
    t_end = max([r.time_s, *r.path_t, *(t for t, _ in r.log)])
    out = []
    for i, (t, text) in enumerate(r.log):
        state, _, note = text.partition(":")
        end = r.log[i + 1][0] if i + 1 < len(r.log) else t_end
        out.append(Phase(state.strip(), t, max(end, t), note.strip()))
    return out


# --- drawing a path ---------------------------------------------------------------------------------------


def draw_path(
    ax: Axes,
    path: Sequence[tuple[float, float, float]],
    *,
    color: str,
    lw: float = 0.9,
    alpha: float = 0.75,
    arrow_every: float = 0.4,
    arrow_size: float = 7.0,
    reverse_color: str = REVERSE_COLOUR,
) -> None:
    """A path in a top view: solid where the robot drove forwards, dashed in ``reverse_color`` where it reversed,
    with an arrow every ``arrow_every`` metres of travel pointing the way it moved (backwards from its heading
    on a reverse leg). ``arrow_every`` <= 0 draws no arrows."""
    if len(path) < 2:
        return
    p = np.asarray(path, dtype=float)
    u, v = -p[:, 1], p[:, 0]
    rev = reverse_mask(path)[1:]  # per step
    # Runs of steps of the same direction, each one polyline.
    start = 0
    for i in range(1, len(rev) + 1):
        if i == len(rev) or rev[i] != rev[start]:
            back = bool(rev[start])
            ax.plot(
                u[start : i + 1],
                v[start : i + 1],
                color=reverse_color if back else color,
                ls=(0, (3, 1.5)) if back else "-",
                lw=lw * 1.3 if back else lw,
                alpha=min(1.0, alpha + 0.15) if back else alpha,
                zorder=3.2 if back else 3,
                solid_capstyle="butt",
            )
            start = i
    if arrow_every <= 0:
        return
    du, dv = np.diff(u), np.diff(v)
    step = np.hypot(du, dv)
    travelled = np.concatenate([[0.0], np.cumsum(step)])
    mark = arrow_every / 2
    while mark < travelled[-1]:
        i = int(np.searchsorted(travelled, mark, side="right")) - 1
        i = min(i, len(step) - 1)
        if step[i] > 1e-9:
            f = (mark - travelled[i]) / step[i]
            x0, y0 = u[i] + f * du[i], v[i] + f * dv[i]
            ex, ey = du[i] / step[i], dv[i] / step[i]
            half = 0.02
            back = bool(rev[i])
            ax.add_patch(
                FancyArrowPatch(
                    (x0 - half * ex, y0 - half * ey),
                    (x0 + half * ex, y0 + half * ey),
                    arrowstyle="-|>",
                    mutation_scale=arrow_size * (1.25 if back else 1.0),
                    lw=0,
                    color=reverse_color if back else color,
                    alpha=min(1.0, alpha + 0.2),
                    shrinkA=0,
                    shrinkB=0,
                    zorder=3.5,
                )
            )
        mark += arrow_every


# --- the executed case against the start region -----------------------------------------------------------


def _share(n: int, total: int) -> str:
    return "–" if not total else f"{100 * n / total:.0f} %"


def agreement_table(results: Sequence[TrialResult], variant_list: Sequence[Variant], *, regions: bool = True) -> str:
    """Markdown: per variant and start region, the runs by the case they executed ("none": never planned) and the
    share that executed their start region's case; ``regions=False`` keeps only each variant's "all" row."""
    planners = [p for _, p in variant_list]
    head = "| variant | start region | runs | " + " | ".join(f"ran {c}" for c in CASES) + " | none | agree |"
    lines = [head, "|---|---|" + "---:|" * (len(CASES) + 3)]
    for v in variant_list:
        runs = [r for r in results if variant_of(r) == v]
        groups = [(str(c), [r for r in runs if r.case == c]) for c in sorted({r.case for r in runs})] if regions else []
        for name, group in [*groups, ("all", runs)]:
            counts = [sum(r.classified_case == c for r in group) for c in CASES]
            agree = sum(r.classified_case == r.case for r in group)
            cells = [str(n) if n else "·" for n in counts]
            none = sum(r.classified_case is None for r in group)
            lines.append(
                f"| {variant_label(v, planners)} | {name} | {len(group)} | {' | '.join(cells)} | "
                f"{none if none else '·'} | {agree}/{len(group)} ({_share(agree, len(group))}) |"
            )
    return "\n".join(lines) + "\n"


def executed_case_table(results: Sequence[TrialResult], variant_list: Sequence[Variant]) -> str:
    """Markdown: per executed case (a row; "none": never planned), each variant's docked / runs."""
    planners = [p for _, p in variant_list]
    labels = [variant_label(v, planners) for v in variant_list]
    lines = [
        "| case executed | " + " | ".join(f"{lab}: docked / runs" for lab in labels) + " |",
        "|---|" + "---:|" * len(labels),
    ]
    executed = sorted({r.classified_case for r in results if r.classified_case is not None})
    rows = [(str(c), [r for r in results if r.classified_case == c]) for c in executed]
    never = [r for r in results if r.classified_case is None]
    if never:
        rows.append(("none (never planned)", never))
    rows.append(("all", list(results)))
    for name, group in rows:
        cells = []
        for v in variant_list:
            g = [r for r in group if variant_of(r) == v]
            ok = sum(r.success for r in g)
            cells.append(f"{ok}/{len(g)}" if g else "–")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# --- the runs with a figure of their own ---------------------------------------------------------------------


def select_runs(results: Sequence[TrialResult], variant_list: Sequence[Variant], cap: int = 40) -> list[TrialResult]:
    """For each variant the first trial of each start region, and every failed run; at most ``cap``, taken in turn
    from the two lists (firsts case by case, failures trial by trial, the variants interleaved). In variant,
    region and trial order."""
    order = {v: i for i, v in enumerate(variant_list)}
    firsts: list[TrialResult] = []
    for case in sorted({r.case for r in results}):
        for v in variant_list:
            runs = [r for r in results if r.case == case and variant_of(r) == v]
            if runs:
                firsts.append(min(runs, key=lambda r: r.trial))
    failed = sorted(
        (r for r in results if not r.success), key=lambda r: (r.trial, r.case, order.get(variant_of(r), len(order)))
    )
    chosen: list[TrialResult] = []
    seen: set[int] = set()
    queues = [firsts, failed]
    k = 0
    while len(chosen) < cap and any(queues):
        queue = queues[k % 2] or queues[(k + 1) % 2]
        r = queue.pop(0)
        k += 1
        if id(r) not in seen:
            seen.add(id(r))
            chosen.append(r)
    return sorted(chosen, key=lambda r: (order.get(variant_of(r), len(order)), r.case, r.trial))


def run_file(r: TrialResult) -> str:
    """The run's figure's name: runs/<method>_<planner>_case<region>_trial<n>.png (file-name safe)."""
    method = re.sub(r"[^A-Za-z0-9]+", "-", r.method).strip("-")
    return f"runs/{method}_{r.planner}_case{r.case}_trial{r.trial}.png"


def nearest_index(times: np.ndarray, t: float) -> int:
    """The sample nearest in time to ``t``."""
    if not len(times):
        return 0
    return int(np.argmin(np.abs(times - t)))
