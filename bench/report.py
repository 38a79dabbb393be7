"""Markdown tables from the results dictionary that ``bench.run`` writes to JSON."""

from __future__ import annotations

import numpy as np

# Sibenik primary, sampling vs. no sampling (SAH), Nabata et al. 2013 Fig. 4(a): t_sah / t_sampling
PAPER_RATIOS = {512: 1.41, 1024: 1.52, 2048: 1.59, 4096: 1.86}


def table(headers: list[str], rows: list[list], right_from: int = 1) -> str:
    """A Markdown table; columns from ``right_from`` on are right-aligned."""
    cells = [[_cell(c) for c in row] for row in rows]
    align = ["---" if i < right_from else "---:" for i in range(len(headers))]
    lines = ["| " + " | ".join(headers) + " |", "| " + " | ".join(align) + " |"]
    lines += ["| " + " | ".join(row) + " |" for row in cells]
    return "\n".join(lines)


def _cell(value) -> str:
    if value is None:
        return "—"
    if isinstance(value, float):
        return f"{value:.3g}" if abs(value) < 0.01 else f"{value:.2f}"
    return str(value)


def _ratio(a, b):
    return None if not a or not b else a / b


def _fmt_x(value):
    return None if value is None else f"{value:.2f}×"


def _vec(v) -> str:
    return "—" if v is None else "(" + ", ".join(f"{float(x):.4g}" for x in v) + ")"


def header(res: dict) -> str:
    m, s = res["machine"], res["scene"]
    cores = f"{m['logical_cores']} logical"
    if m.get("physical_cores"):
        cores += f", {m['physical_cores']} physical"
    if m.get("usable_cores") and m["usable_cores"] != m["logical_cores"]:
        cores += f", {m['usable_cores']} usable"
    mem = f", {m['memory_bytes'] / 2**30:.0f} GiB RAM" if m.get("memory_bytes") else ""
    versions = ", ".join(f"{k} {v}" for k, v in m["versions"].items() if v)
    b = np.asarray(s["bounds"])
    lines = [
        f"# dacrt benchmark: {s['name']}",
        "",
        f"- machine: {m['cpu_model']} ({cores}{mem}); Python {m['python']}; {versions}",
        f"- scene: `{s['path']}`: {s['triangles']:,} triangles, {s['vertices']:,} vertices, "
        f"bounds {np.round(b[0], 3).tolist()} → {np.round(b[1], 3).tolist()}, "
        f"diagonal {s['diagonal']:.4g}",
        f"- view `{s['view_key']}`: eye {_vec(s['view']['eye'])}, "
        f"target {_vec(s['view']['target'])}, "
        f"up {_vec(s['view']['up'])}, fov {s['view']['fov_deg']:.4g}°, "
        f"light {_vec(s['view'].get('light'))}",
        f"- medians of {res['args']['repeat']} runs, engines alternating within each run; "
        f"seed {res['args']['seed']}"
        + (
            f"; dacrt.warmup() {_cell(res['dacrt_warmup_s'])} s"
            if res.get("dacrt_warmup_s") is not None
            else ""
        ),
    ]
    for family, reason in res.get("missing", {}).items():
        lines.append(f"- **{family} not available**: {reason}")
    return "\n".join(lines)


def _configs(res: dict):
    """Ordered (key, family, name, threads) of every engine configuration in the results."""
    seen = {}
    for kind in res["kinds"].values():
        for key, run in kind["runs"].items():
            seen.setdefault(key, (key, run["family"], run["name"], run["threads"]))
    return list(seen.values())


def speed_tables(res: dict, field: str, title: str) -> str:
    """Mrays/s per kind x threads, one column per engine; Embree's column is its 1-thread figure."""
    configs = _configs(res)
    threads = sorted({c[3] for c in configs if c[1] != "embree"}) or [1]
    names = []
    for _, _family, name, _ in configs:
        if name not in names:
            names.append(name)
    strategies = [n for n in names if n not in ("embree", "open3d")]
    heads = ["kind", "rays", "threads"] + [f"{n} (1 thread)" if n == "embree" else n for n in names]
    if "sampling" in strategies and "sah" in strategies:
        heads.append("sampling/sah")
    if strategies and "embree" in names:
        heads.append(f"{strategies[0]}/embree")
    rows = []
    for kind, info in res["kinds"].items():
        for t in threads:

            def get(name, t=t, info=info):
                key = f"{name}@1" if name == "embree" else f"{name}@{t}"
                run = info["runs"].get(key)
                return run.get(field) if run else None

            row = [kind, f"{info['n_rays']:,}", t] + [get(n) for n in names]
            if "sampling" in strategies and "sah" in strategies:
                row.append(_fmt_x(_ratio(get("sampling"), get("sah"))))
            if strategies and "embree" in names:
                row.append(_fmt_x(_ratio(get(strategies[0]), get("embree"))))
            rows.append(row)
    cut = sorted(
        {
            (
                f"{run['name']}@{run['threads']} ({kind}: {len(run['trace_s'])} of "
                f"{res['args']['repeat']} runs)"
            )
            for kind, info in res["kinds"].items()
            for run in info["runs"].values()
            if run.get("cut_short")
        }
    )
    note = f"\n\nFewer runs (a trace took longer than --slow): {', '.join(cut)}" if cut else ""
    return f"## {title}\n\n" + table(heads, rows, right_from=1) + note


def build_table(res: dict) -> str:
    """Median build time per engine configuration, over the build + trace runs of every kind."""
    rows = []
    for key, family, name, t in _configs(res):
        builds = [
            v
            for kind in res["kinds"].values()
            if key in kind["runs"]
            for v in kind["runs"][key]["build_s"]
        ]
        what = {
            "dacrt": "dacrt.Scene(...)",
            "embree": "EmbreeScene + TriangleMesh((F,3,3)) + commit",
            "open3d": "RaycastingScene + add_triangles + commit",
        }[family]
        rows.append([name, t, what, None if not builds else 1e3 * float(np.median(builds))])
    return "## Build time per frame (ms, median over all build + trace runs)\n\n" + table(
        ["engine", "threads", "what is timed", "build ms"], rows, right_from=3
    )


def scaling_table(res: dict) -> str | None:
    configs = [c for c in _configs(res) if c[1] != "embree"]
    threads = sorted({c[3] for c in configs})
    if len(threads) < 2:
        return None
    top = threads[-1]
    names = []
    for c in configs:
        if c[2] not in names:
            names.append(c[2])
    rows = []
    for kind, info in res["kinds"].items():
        row = [kind]
        for n in names:
            one, many = info["runs"].get(f"{n}@1"), info["runs"].get(f"{n}@{top}")
            row.append(_fmt_x(_ratio(many and many["trace_mrays"], one and one["trace_mrays"])))
        rows.append(row)
    return (
        f"## Thread scaling, trace only: speed at {top} threads / speed at 1 thread "
        "(target ≥ 1.8× at 2)\n\n" + table(["kind"] + names, rows)
    )


def stats_table(res: dict) -> str | None:
    strategies = []
    for info in res["kinds"].values():
        for s in info.get("stats", {}):
            if s not in strategies:
                strategies.append(s)
    if not strategies:
        return None
    heads = ["kind"]
    for s in strategies:
        heads += [f"{s} box/ray", f"{s} tri/ray"]
    both = "sampling" in strategies and "sah" in strategies
    if both:
        heads += ["box tests sampling/sah", "tri tests sampling/sah"]
    rows = []
    for kind, info in res["kinds"].items():
        st = info.get("stats", {})
        row = [kind]
        for s in strategies:
            row += [st.get(s, {}).get("box_per_ray"), st.get(s, {}).get("tri_per_ray")]
        if both:
            a, b = st.get("sampling", {}), st.get("sah", {})
            row += [
                _ratio(a.get("box_per_ray"), b.get("box_per_ray")),
                _ratio(a.get("tri_per_ray"), b.get("tri_per_ray")),
            ]
        rows.append(row)
    return (
        "## Intersection tests per ray (dacrt `stats=True`, 1 thread; paper Fig. 10 reports the "
        "box-test ratio to Afra's method, i.e. sampling/sah)\n\n" + table(heads, rows)
    )


def _pct(fraction: float) -> str:
    """A percentage with 3 decimals, rounded down so that anything short of all shows below 100."""
    return "100" if fraction >= 1.0 else f"{np.floor(fraction * 1e5) / 1e3:.3f}"


def agreement_table(res: dict) -> str | None:
    configs = [c for c in _configs(res) if c[1] != "embree"]
    names = []
    for c in configs:
        if c[2] not in names:
            names.append(c[2])
    rows, any_value = [], False
    for kind, info in res["kinds"].items():
        row = [kind, info["query"]]
        for n in names:
            agreements = [
                r["agreement"]
                for k, r in info["runs"].items()
                if r["name"] == n and r.get("agreement")
            ]
            if not agreements:
                row.append(None)
                continue
            any_value = True
            worst = {
                f: min(a[f] for a in agreements) for f in agreements[0] if f in ("hit", "t", "prim")
            }
            row.append(" / ".join(_pct(worst[f]) for f in ("hit", "t", "prim") if f in worst))
        rows.append(row)
    if not any_value:
        return None
    tol = res["scene"]["diagonal"] * 1e-4
    return (
        "## Agreement with Embree, % of rays (worst over thread counts)\n\n"
        f"closest: same hit/miss / of common hits |t − t_embree| ≤ {tol:.3g} (1e-4 × diagonal) "
        "/ same triangle; "
        "occluded: same answer\n\n" + table(["kind", "query"] + names, rows, right_from=2)
    )


def memory_table(res: dict) -> str | None:
    mem = res.get("memory") or []
    lines = []
    if mem:
        n_tri = res["scene"]["triangles"]
        rows = []
        for m in mem:
            if "error" in m:
                rows.append(
                    [
                        m["name"],
                        m["threads"],
                        m["kind"],
                        f"{m['n_rays']:,}",
                        "error: " + m["error"],
                        None,
                        None,
                        None,
                        None,
                    ]
                )
                continue
            above = m["above_idle"]
            budget = 100 * m["n_rays"] + 100 * n_tri
            mib = f"{above / 2**20:.1f}" + (" (≤)" if m["upper_bound_only"] else "")
            rows.append(
                [
                    m["name"],
                    m["threads"],
                    m["kind"],
                    f"{m['n_rays']:,}",
                    f"{m['build_above_idle'] / 2**20:.1f}",
                    mib,
                    above / m["n_rays"],
                    above / n_tri,
                    f"{100 * above / budget:.0f}%",
                ]
            )
        lines.append(
            "## Peak memory (RSS) of one build + trace, each in a fresh process\n\n"
            "MiB above the process with its inputs loaded and the engine warmed up; "
            "B/ray and B/triangle divide the build + trace figure by the rays or by the "
            "triangles\n\n"
            + table(
                [
                    "engine",
                    "threads",
                    "kind",
                    "rays",
                    "build MiB",
                    "build + trace MiB",
                    "B/ray",
                    "B/triangle",
                    "of budget 100 B/ray + 100 B/tri",
                ],
                rows,
                right_from=3,
            )
        )
    if res.get("peak_rss_bytes"):
        lines.append(
            f"Whole run (this process): peak RSS {res['peak_rss_bytes'] / 2**20:.0f} MiB, "
            f"{(res['peak_rss_bytes'] - res['idle_rss_bytes']) / 2**20:.0f} MiB "
            "above the idle process "
            f"(scene loaded, engines imported and warmed up)."
        )
    return "\n\n".join(lines) if lines else None


def resolution_table(res: dict) -> str:
    rows = []
    for r in res["resolutions"]:
        rows.append(
            [
                f"{r['width']}²",
                f"{r['n_rays']:,}",
                r["threads"],
                None if r.get("sampling_s") is None else 1e3 * r["sampling_s"],
                None if r.get("sah_s") is None else 1e3 * r["sah_s"],
                _fmt_x(r.get("ratio")),
                _fmt_x(r.get("paired_ratio")),
                _fmt_x(PAPER_RATIOS.get(r["width"])),
                r.get("sampling_box_per_ray"),
                r.get("sah_box_per_ray"),
                None if r.get("embree_s") is None else 1e3 * r["embree_s"],
            ]
        )
    return (
        "## Ray-sampling ablation: primary rays, trace only "
        "(paper: Nabata et al. 2013 Fig. 4(a), Sibenik, 1 thread)\n\n"
        "ratio = time sah / time sampling (the speed-up from sampling), of the medians; "
        "paired: the median of each repetition's ratio "
        "(steadier when the machine's load drifts)\n\n"
        + table(
            [
                "resolution",
                "rays",
                "threads",
                "sampling ms",
                "sah ms",
                "sah/sampling",
                "sah/sampling, paired",
                "paper",
                "sampling box/ray",
                "sah box/ray",
                "embree ms (1 thread)",
            ],
            rows,
        )
    )


def render(res: dict) -> str:
    parts = [header(res)]
    if res.get("kinds"):
        parts += [
            speed_tables(res, "trace_mrays", "Trace only, Mrays/s"),
            speed_tables(
                res,
                "build_trace_mrays",
                "Build + trace (per-frame cost: a new scene, then the trace), Mrays/s",
            ),
            build_table(res),
        ]
        parts += [p for p in (scaling_table(res), stats_table(res), agreement_table(res)) if p]
        rows = [
            [
                k,
                v["query"],
                f"{v['n_rays']:,}",
                None if v["tmax"] is None else v["tmax"],
                None if v.get("reference_hit") is None else f"{100 * v['reference_hit']:.1f}%",
            ]
            for k, v in res["kinds"].items()
        ]
        parts.append(
            "## Ray sets\n\n"
            + table(
                ["kind", "query", "rays", "tmax", "hit / occluded (Embree)"], rows, right_from=2
            )
        )
    if res.get("resolutions"):
        parts.append(resolution_table(res))
    mem = memory_table(res)
    if mem:
        parts.append(mem)
    return "\n\n".join(parts) + "\n"
