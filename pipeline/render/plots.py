"""The dataset card's plots (``DIR/card/*.png``) and the label statistics they draw.

:func:`label_stats` reads what the plots show from the finished labels: gaze pitch / yaw in the
camera frame (our convention, ``gaze.camera``: pitch + = up, yaw + = toward image right), the head
pose relative to the camera (``head_pose.camera_pitch_deg`` / ``camera_yaw_deg``: the head-frame
direction from the head toward the camera; pitch + = camera above, yaw + = toward the subject's
left), images per asset, the imaged eye's radius and the distance from its rotation centre to its
iris plane (``eyes.<eye>.radius_mm`` / ``center_to_iris_plane_mm``; None when the labels carry
neither) and the share of images in which each of the 28 landmarks is visible
(``landmarks.visible``; None when the labels carry no visibility). ``dataset.json`` keeps these
numbers (``statistics``), so the card's text and the plots say the same.

:func:`write_plots` draws them with matplotlib's Agg canvas (no pyplot, no global backend, the
default style whatever the user's matplotlibrc says, no ``Software`` tag in the PNG), so the same
labels give the same bytes.
"""

from __future__ import annotations

import io
import math

import numpy as np

from pipeline.io.atomic import write_bytes

#: What each of the card's plots shows (``card/<name>``: pipeline/render/run.py CARD_PLOTS and, for
#: the lighting and eye configuration plots, pipeline/render/plan.py OWN_FILES are the files a run
#: deletes and rewrites).
PLOTS = {
    "gaze.png": "histograms of the gaze pitch and yaw in the camera frame",
    "head_pose.png": "histograms of the head pose relative to the camera",
    "assets.png": "images per asset",
    "eye.png": "histograms of the imaged eye's radius and of the distance from its centre to its iris plane",
    "visibility.png": "share of images in which each landmark is visible",
    "lighting.png": "images per environment map and a histogram of the lighting strength",
    "eye_configuration.png": "images per iris colour, sclera tint and veins variant, and a histogram of the "
                             "pupil radius",
}
BIN_DEG = 5.0
BIN_MM = 0.1
BIN_STRENGTH = 0.1
BIN_PUPIL_MM = 0.25
#: Short names of the 28 landmarks (pipeline/render/labels.py LANDMARK_ORDER) for the plot's axis.
LANDMARK_NAMES = (["medial canthus"] + [f"upper lid {k}" for k in range(1, 6)] + ["lateral canthus"]
                  + [f"lower lid {k}" for k in range(1, 6)] + [f"iris {k}" for k in range(8)]
                  + [f"pupil {k}" for k in range(8)])


def _hist(values, step: float = BIN_DEG) -> dict:
    """Counts over bins of ``step`` (:data:`BIN_DEG` degrees, :data:`BIN_MM` mm) aligned to multiples
    of it (edges (k+1,), counts (k,))."""
    v = np.asarray(values, float)
    k0 = math.floor(round(v.min() / step, 9))          # 12.0 / 0.1 is 119.99999999999999
    k1 = max(math.ceil(round(v.max() / step, 9)), k0 + 1)
    if k1 * step <= v.max():                # np.histogram's last bin is closed: keep it a full bin
        k1 += 1
    edges = np.round(np.arange(k0, k1 + 1) * step, 9)
    counts, _ = np.histogram(v, edges)
    return {"edges": [float(e) for e in edges], "counts": [int(c) for c in counts],
            "min": round(float(v.min()), 4), "max": round(float(v.max()), 4),
            "mean": round(float(v.mean()), 4)}


def label_stats(labels, asset_names) -> dict:
    """What the card's plots show, from every label of the dataset.

    Parameters
    ----------
    labels : iterable of dict   the label documents (``asset.name`` names each image's asset)
    asset_names : list of str   every asset of the plan, in ``--assets`` order (an asset with no
                                image still gets its 0)

    Returns
    -------
    dict  ``gaze_camera_deg`` and ``head_pose_deg`` (``pitch`` / ``yaw``: :func:`_hist`),
          ``images_per_asset`` {name: n}, ``eye_mm`` (``radius`` / ``center_to_iris_plane``:
          :func:`_hist` of the imaged eye's, 0.1 mm bins, or None when a label lacks them),
          ``landmark_visible_share`` (28 floats, 4 decimals, or None without visibility), ``n_images``,
          ``landmarks_inside`` (images with all 28 landmarks inside the image, their share, the
          smallest distance of a landmark to the border in px (negative: outside), images with each
          landmark outside), ``lighting`` (images per map, strength histogram) and ``eye_configuration``
          (images per iris colour, sclera tint, veins; pupil radius histogram, 0.25 mm bins); None
          when the labels lack them
    """
    gp, gy, hp, hy, radius, iris = [], [], [], [], [], []
    per_asset = {name: 0 for name in asset_names}
    visible, n_vis, n = np.zeros(28, np.int64), 0, 0
    hdri, strength, pupil, config = {}, [], [], {"iris_color": {}, "sclera_tint": {}, "veins": {}}
    outside, all_inside, margins = np.zeros(28, np.int64), 0, []
    for d in labels:
        n += 1
        light = d.get("lighting") or {}
        if "hdri" in light:
            hdri[light["hdri"]] = hdri.get(light["hdri"], 0) + 1
            strength.append(light["strength"])
        ec = d.get("eye_configuration") or {}
        for k, counts in config.items():
            if k in ec:
                counts[ec[k]] = counts.get(ec[k], 0) + 1
        if "pupil_radius_mm" in ec:
            pupil.append(ec["pupil_radius_mm"])
        if "image" in d:
            px = np.asarray(d["landmarks"]["px"], float)
            w, h = d["image"]["width"], d["image"]["height"]
            m = np.min([px[:, 0], w - px[:, 0], px[:, 1], h - px[:, 1]], axis=0)      # per landmark, px
            outside += m < 0
            all_inside += bool((m >= 0).all())
            margins.append(float(m.min()))
        g = d["gaze"]["camera"]
        gp.append(g["pitch_deg"])
        gy.append(g["yaw_deg"])
        hp.append(d["head_pose"]["camera_pitch_deg"])
        hy.append(d["head_pose"]["camera_yaw_deg"])
        eye = (d.get("eyes") or {}).get(d["gaze"]["eye"]) or {}
        if "radius_mm" in eye and "center_to_iris_plane_mm" in eye:
            radius.append(eye["radius_mm"])
            iris.append(eye["center_to_iris_plane_mm"])
        name = (d.get("asset") or {}).get("name", d.get("scan"))
        per_asset[name] = per_asset.get(name, 0) + 1
        vis = d["landmarks"].get("visible")
        if vis is not None:
            visible += np.asarray(vis, bool)
            n_vis += 1
    if n == 0:
        raise ValueError("no labels to plot")
    share = [round(float(v) / n, 4) for v in visible] if n_vis == n else None
    return {"n_images": n,
            "gaze_camera_deg": {"pitch": _hist(gp), "yaw": _hist(gy)},
            "head_pose_deg": {"pitch": _hist(hp), "yaw": _hist(hy)},
            "images_per_asset": per_asset,
            "eye_mm": ({"radius": _hist(radius, BIN_MM), "center_to_iris_plane": _hist(iris, BIN_MM)}
                       if len(radius) == n else None),
            "landmark_visible_share": share,
            "landmarks_inside": ({"images_all_inside": int(all_inside), "share": round(all_inside / n, 4),
                                  "min_margin_px": round(min(margins), 3),
                                  "outside_per_landmark": [int(x) for x in outside]} if len(margins) == n else None),
            "lighting": ({"hdri": dict(sorted(hdri.items())), "strength": _hist(strength, BIN_STRENGTH)}
                         if len(strength) == n else None),
            "eye_configuration": ({**{k: dict(sorted(v.items())) for k, v in config.items()},
                                   "pupil_radius_mm": _hist(pupil, BIN_PUPIL_MM)} if len(pupil) == n else None)}


def _bars(ax, h: dict, xlabel: str, color: str) -> None:
    e = np.asarray(h["edges"])
    ax.bar(e[:-1], h["counts"], width=np.diff(e), align="edge", color=color, edgecolor="white", linewidth=0.5)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("images")
    ax.grid(axis="y", alpha=0.3)


def _save(fig, path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, metadata={"Software": None})
    write_bytes(path, buf.getvalue())


def _pair(path, title: str, a: dict, b: dict, xa: str, xb: str, color: str) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 3.4), layout="constrained")
    axs = fig.subplots(1, 2)
    _bars(axs[0], a, xa, color)
    _bars(axs[1], b, xb, color)
    fig.suptitle(title)
    _save(fig, path)


def write_plots(out, stats: dict) -> list:
    """Draw the card's plots of ``stats`` (:func:`label_stats`) into the folder ``out`` (a Path);
    returns their paths relative to it (run.py ``CARD_PLOTS``; no ``visibility.png`` without
    visibility, no ``eye.png`` without the eyes' radius and iris plane)."""
    import matplotlib.style
    from matplotlib.figure import Figure

    path = {name: out / "card" / name for name in PLOTS}
    path["gaze.png"].parent.mkdir(parents=True, exist_ok=True)
    n = stats["n_images"]
    with matplotlib.style.context("default"):
        g, h = stats["gaze_camera_deg"], stats["head_pose_deg"]
        _pair(path["gaze.png"], f"Gaze in the camera frame ({n} images; (0, 0) looks at the camera)",
              g["pitch"], g["yaw"], "gaze pitch (deg, + = up)", "gaze yaw (deg, + = toward image right)",
              "tab:red")
        _pair(path["head_pose.png"], "Head pose relative to the camera (direction from the head to the camera)",
              h["pitch"], h["yaw"], "camera pitch (deg, + = camera above the head's level)",
              "camera yaw (deg, + = toward the subject's left)", "tab:blue")

        per = stats["images_per_asset"]
        fig = Figure(figsize=(7, 0.9 + 0.32 * len(per)), layout="constrained")
        ax = fig.subplots()
        names = list(per)
        ax.barh(range(len(names)), [per[k] for k in names], color="tab:green")
        ax.set_yticks(range(len(names)), names)
        ax.invert_yaxis()                     # --assets order, top down
        for k, name in enumerate(names):
            ax.annotate(str(per[name]), (per[name], k), xytext=(3, 0), textcoords="offset points",
                        va="center", fontsize=8)
        ax.set_xlabel("images")
        ax.set_title(f"Images per asset ({n} in all)")
        ax.margins(x=0.12)
        _save(fig, path["assets.png"])

        eye = stats.get("eye_mm")
        if eye is not None:
            _pair(path["eye.png"], f"The imaged eye ({n} images; from the asset: eyes.<eye> in the labels)",
                  eye["radius"], eye["center_to_iris_plane"], "eyeball radius (mm)",
                  "rotation centre to iris plane (mm)", "tab:purple")

        share = stats["landmark_visible_share"]
        if share is not None:
            fig = Figure(figsize=(9, 3.6), layout="constrained")
            ax = fig.subplots()
            cols = ["tab:green"] * 12 + ["tab:cyan"] * 8 + ["goldenrod"] * 8
            ax.bar(range(28), [100 * s for s in share], color=cols)
            ax.set_xticks(range(28), [f"{k} {LANDMARK_NAMES[k]}" for k in range(28)], rotation=90, fontsize=7)
            ax.set_ylim(0, 100)
            ax.set_ylabel("visible in % of images")
            ax.set_title("Landmark visibility (green: eyelid 0-11, cyan: iris 12-19, yellow: pupil 20-27)")
            ax.grid(axis="y", alpha=0.3)
            _save(fig, path["visibility.png"])
        light = stats.get("lighting")
        if light is not None:
            fig = Figure(figsize=(9, 3.4), layout="constrained")
            axs = fig.subplots(1, 2)
            _counts(axs[0], light["hdri"], "tab:orange")
            axs[0].set_title("environment map")
            _bars(axs[1], light["strength"], "lighting strength", "tab:orange")
            fig.suptitle(f"Lighting ({n} images; the map also turns uniformly about the head's up axis)")
            _save(fig, path["lighting.png"])
        conf = stats.get("eye_configuration")
        if conf is not None:
            fig = Figure(figsize=(12, 3.4), layout="constrained")
            axs = fig.subplots(1, 4)
            for ax, key in zip(axs[:3], ("iris_color", "sclera_tint", "veins")):
                _counts(ax, conf[key], "tab:cyan")
                ax.set_title(key.replace("_", " "))
            _bars(axs[3], conf["pupil_radius_mm"], "pupil radius (mm)", "tab:cyan")
            fig.suptitle(f"Eye configuration ({n} images; eye_configuration in the labels)")
            _save(fig, path["eye_configuration.png"])
    drawn = {"visibility.png": share is not None, "eye.png": eye is not None, "lighting.png": light is not None,
             "eye_configuration.png": conf is not None}
    return [f"card/{name}" for name in PLOTS if drawn.get(name, True)]


def _counts(ax, counts: dict, color: str) -> None:
    """Horizontal bars of ``{name: images}``, the first name on top."""
    names = list(counts)
    ax.barh(range(len(names)), [counts[k] for k in names], color=color)
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("images")
