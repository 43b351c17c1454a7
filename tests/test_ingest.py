"""Stage ingest: good inputs in every format, repairs, real scans.

The scan-folder builders (a head-sized ellipsoid with two eye bumps) live in tests/fixtures/scans.py.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fixtures import (ROOT, head_mesh, ingest, make_scan, sphere_uv, write_obj, write_ply, write_png,
                      write_sidecar)
from pipeline.io.meshfile import load_mesh


def read_metrics(out):
    """The stage's metrics merged with its timings file (wall time, peak memory)."""
    from stages._common import read_stage_metrics

    return read_stage_metrics(Path(out).with_suffix(".metrics.json"))


# ---------------------------------------------------------------------------- tests

def test_good_ply_ingests(tmp_path):
    V, F, hints = make_scan(tmp_path / "head")
    out = tmp_path / "build" / "ingest"
    assert ingest(tmp_path / "head", out) == 0
    mesh = load_mesh(out / "mesh.npz")
    assert mesh["V"].dtype == np.float64 and mesh["F"].dtype == np.int64
    assert mesh["F"].shape == F.shape and mesh["V"].shape == V.shape
    np.testing.assert_allclose(mesh["V"], V.astype(np.float32), atol=1e-9)  # PLY stored float32
    scan = json.loads((out / "scan.json").read_text())
    assert scan["name"] == "head" and scan["texture"] is None and scan["licence"] == "CC0 test data"
    assert scan["folder"] == str(tmp_path / "head")      # what later stages name on a refusal
    assert len(scan["source_sha256"]) == 64
    np.testing.assert_allclose(scan["eyes"]["left"]["hint"], hints["left"])
    assert (scan["units_in"], scan["up_axis_in"], scan["forward_axis_in"]) == ("mm", "+Y", "+Z")
    m = read_metrics(out)
    assert m["faces_in"] == m["faces_out"] == len(F)
    assert all(v == 0 for k, v in m["repairs"].items() if k != "components")
    assert m["hint_surface_distance_mm"]["left"] == pytest.approx(1.0, abs=0.3)
    assert m["flipped_winding"] is False
    assert m["edges"] == {"edges": 3 * len(F) // 2, "boundary": 0, "non_manifold": 0, "inconsistent_winding": 0}
    assert "wall_time_s" in m and "peak_memory_mib" in m
    assert not (out / "texture.png").exists()
    # outward winding: the mesh's signed volume is positive
    T = mesh["V"][mesh["F"]]
    assert np.einsum("ij,ij->i", T[:, 0], np.cross(T[:, 1], T[:, 2])).sum() > 0


def test_an_eye_declared_open_reaches_remove_eyeballs(tmp_path):
    """scan.yaml's ``eyes.<side>.open: true`` is carried into scan.json for that eye alone and
    read back by the record remove_eyeballs reads; ``open: false`` writes what no key writes."""
    import yaml

    from pipeline.io.scan_file import read_scan_record

    make_scan(tmp_path / "head")
    data = yaml.safe_load((tmp_path / "head" / "scan.yaml").read_text())
    data["eyes"]["right"]["open"] = True
    data["eyes"]["left"]["open"] = False
    (tmp_path / "head" / "scan.yaml").write_text(yaml.safe_dump(data))
    out = tmp_path / "build" / "ingest"
    assert ingest(tmp_path / "head", out) == 0
    scan = json.loads((out / "scan.json").read_text())
    assert scan["eyes"]["right"]["open"] is True and set(scan["eyes"]["left"]) == {"hint"}
    assert read_scan_record(out).open_eyes == ("right",)


def test_obj_with_seams_mtl_texture(tmp_path):
    """Per-corner UVs survive exactly (positions are not split at seams); MTL map_Kd texture is kept."""
    folder = tmp_path / "objscan"
    folder.mkdir()
    V, F, hints = head_mesh()
    rng = np.random.default_rng(0)
    # one UV row per corner, so every edge is a seam
    UV = rng.uniform(0, 1, (3 * len(F), 2))
    FUV = np.arange(3 * len(F)).reshape(-1, 3)
    write_obj(folder / "scan.obj", V, F, UV=UV, FUV=FUV, mtl="scan.mtl")
    (folder / "scan.mtl").write_text("newmtl skin\nKd 1 1 1\nmap_Kd tex/skin.png\n")
    (folder / "tex").mkdir()
    write_png(folder / "tex" / "skin.png", (64, 32))
    write_sidecar(folder, hints, mesh="scan.obj")
    out = tmp_path / "out"
    assert ingest(folder, out) == 0
    mesh = load_mesh(out / "mesh.npz")
    assert len(mesh["V"]) == len(V)                    # not split at seams
    np.testing.assert_allclose(mesh["V"], V, atol=1e-12)
    np.testing.assert_array_equal(mesh["F"], F)
    np.testing.assert_allclose(mesh["UV"][mesh["FUV"]], UV[FUV], atol=1e-12)
    from PIL import Image
    with Image.open(out / "texture.png") as img:
        assert img.size == (64, 32)
    scan = json.loads((out / "scan.json").read_text())
    assert scan["texture"] == "texture.png"
    assert read_metrics(out)["files_read"] == ["scan.mtl", "scan.obj", "scan.yaml", "tex/skin.png"]


def test_obj_quads_negative_indices_and_vertex_colours(tmp_path):
    folder = tmp_path / "quads"
    folder.mkdir()
    V, F, hints = head_mesh()
    # same surface, but the first face written as a quad made of two triangles sharing an edge is hard;
    # instead append a far-away quad (debris) using negative indices and coloured vertices
    lines = [f"v {x!r} {y!r} {z!r} 0.5 0.25 1.0" for x, y, z in V.tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
    lines += ["v 0 -160 0 0 0 0", "v 5 -160 0 0 0 0", "v 5 -155 0 0 0 0", "v 0 -155 0 0 0 0", "f -4 -3 -2 -1"]
    (folder / "scan.obj").write_text("\n".join(lines) + "\n")
    write_sidecar(folder, hints, mesh="scan.obj")
    out = tmp_path / "out"
    assert ingest(folder, out) == 0
    m = read_metrics(out)
    assert m["polygons_triangulated"] == 1 and m["faces_in"] == len(F) + 2
    assert m["repairs"]["debris_components"] == 1 and m["repairs"]["debris_faces"] == 2
    assert m["repairs"]["unreferenced_vertices"] == 4
    mesh = load_mesh(out / "mesh.npz")
    assert mesh["VC"].shape == (len(V), 3)
    np.testing.assert_array_equal(mesh["VC"][0], [128, 64, 255])


@pytest.mark.parametrize("binary", [True, False])
def test_ply_with_st_uv_texture_and_colours(tmp_path, binary):
    """The synthetic-head layout: PLY with per-vertex s,t and a texture named in scan.yaml."""
    folder = tmp_path / "syn"
    folder.mkdir()
    V, F, hints = head_mesh(3)
    uv = sphere_uv(V)
    vc = np.full((len(V), 3), 200, dtype=np.uint8)
    write_ply(folder / "scan.ply", V, F, binary=binary, uv=uv, vc=vc)
    write_png(folder / "texture.png", (32, 16))
    write_sidecar(folder, hints, texture="texture.png")
    out = tmp_path / "out"
    assert ingest(folder, out) == 0
    mesh = load_mesh(out / "mesh.npz")
    np.testing.assert_allclose(mesh["UV"][mesh["FUV"]], uv[F].astype(np.float32), atol=1e-6)
    assert mesh["VC"].shape == (len(V), 3) and (mesh["VC"] == 200).all()
    assert (out / "texture.png").read_bytes() == (folder / "texture.png").read_bytes()  # PNG copied


def test_stl_and_glb(tmp_path):
    import trimesh

    V, F, hints = head_mesh(3)
    for ext in ("stl", "glb"):
        folder = tmp_path / ext
        folder.mkdir()
        tm = trimesh.Trimesh(V, F, process=False)
        if ext == "glb":
            from PIL import Image
            tm.visual = trimesh.visual.TextureVisuals(uv=sphere_uv(V), image=Image.new("RGB", (16, 8), (9, 99, 199)))
        tm.export(folder / f"scan.{ext}")
        write_sidecar(folder, hints, mesh=f"scan.{ext}")
        out = tmp_path / f"out_{ext}"
        assert ingest(folder, out) == 0, ext
        mesh = load_mesh(out / "mesh.npz")
        assert len(mesh["F"]) == len(F)
        assert len(mesh["V"]) == len(V)            # the STL soup is merged back
        m = read_metrics(out)
        if ext == "stl":
            assert m["repairs"]["merged_vertices"] == 3 * len(F) - len(V)
        else:
            np.testing.assert_allclose(mesh["UV"][mesh["FUV"]], sphere_uv(V)[F], atol=1e-6)
            assert json.loads((out / "scan.json").read_text())["texture"] == "texture.png"


def test_debris_removed_and_counted(tmp_path):
    folder = tmp_path / "debris"
    folder.mkdir()
    V, F, hints = head_mesh()
    import trimesh

    blob = trimesh.creation.icosphere(0)                      # 20 faces < 1 % of 5120
    far = np.asarray(blob.vertices) * 3 + [0, -160, 20]       # below the chin
    near = np.asarray(blob.vertices) * 2 + hints["left"] + [0, 0, 6]  # floating just in front of the left eye
    Vall = np.vstack([V, far, near])
    Fall = np.vstack([F, blob.faces + len(V), blob.faces + len(V) + len(far)])
    # plus exact duplicates and a degenerate face far from the eyes
    low = np.argsort(V[F].mean(axis=1)[:, 1])[:3]             # the three lowest faces (chin)
    Fall = np.vstack([Fall, F[low], [[F[low[0], 0], F[low[0], 0], F[low[0], 1]]]])
    write_ply(folder / "scan.ply", Vall, Fall)
    write_sidecar(folder, hints)
    out = tmp_path / "out"
    assert ingest(folder, out) == 0
    r = read_metrics(out)["repairs"]
    assert r["debris_components"] == 1 and r["debris_faces"] == 20
    assert r["small_components_kept_near_eyes"] == 1
    assert r["duplicate_faces"] == 3 and r["degenerate_faces"] == 1
    assert r["unreferenced_vertices"] == len(far)
    mesh = load_mesh(out / "mesh.npz")
    assert len(mesh["F"]) == len(F) + 20 and len(mesh["V"]) == len(V) + len(near)
    assert mesh["V"][:, 1].min() > -110                       # the far blob is gone


def test_repairs_near_eye_refused(tmp_path, capsys):
    folder = tmp_path / "eyedamage"
    folder.mkdir()
    V, F, hints = head_mesh()
    c = V[F].mean(axis=1)
    near = F[np.linalg.norm(c - hints["left"], axis=1) < 20]
    write_ply(folder / "scan.ply", V, np.vstack([F, near]))  # duplicate every face around the left eye
    write_sidecar(folder, hints)
    out = tmp_path / "out"
    assert ingest(folder, out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "scan.ply" in err and "left eye hint" in err and "repairs would remove" in err
    assert not out.exists()


def test_inward_winding_flipped(tmp_path):
    folder = tmp_path / "inward"
    folder.mkdir()
    V, F, hints = head_mesh(3)
    write_ply(folder / "scan.ply", V, F[:, ::-1])
    write_sidecar(folder, hints)
    out = tmp_path / "out"
    assert ingest(folder, out) == 0
    assert read_metrics(out)["flipped_winding"] is True
    np.testing.assert_array_equal(np.sort(load_mesh(out / "mesh.npz")["F"], axis=1), np.sort(F, axis=1))


def test_subprocess_cli_and_stale_free_rerun(tmp_path):
    make_scan(tmp_path / "cli")
    out = tmp_path / "build" / "cli" / "ingest"
    metrics = tmp_path / "build" / "cli" / "ingest.metrics.json"
    cmd = [sys.executable, "-m", "stages.ingest", str(tmp_path / "cli"), str(out), "--metrics", str(metrics)]
    for _ in range(2):  # a re-run replaces the folder atomically
        p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert p.returncode == 0, p.stderr
    assert sorted(x.name for x in out.iterdir()) == ["mesh.npz", "scan.json"]
    assert json.loads(metrics.read_text())["faces_out"] == 5120
    assert [x.name for x in out.parent.iterdir() if ".tmp-" in x.name] == []


# ---------------------------------------------------------------------------- real scans

def _obj_corners(path):
    """Independent reference parse of an OBJ's (position, uv) per corner, by a plain loop."""
    v, vt, corners = [], [], set()
    for line in Path(path).read_text().splitlines():
        t = line.split()
        if not t:
            continue
        if t[0] == "v":
            v.append(tuple(float(x) for x in t[1:4]))
        elif t[0] == "vt":
            vt.append(tuple(float(x) for x in t[1:3]))
        elif t[0] == "f":
            for c in t[1:]:
                a, b = c.split("/")[:2]
                corners.add((v[int(a) - 1], vt[int(b) - 1]))
    return corners


def test_real_james(extra_scan, tmp_path):
    folder = extra_scan("james")
    out = tmp_path / "james"
    assert ingest(folder, out) == 0
    mesh = load_mesh(out / "mesh.npz")
    from PIL import Image
    with Image.open(out / "texture.png") as img:
        assert img.size == (2400, 1600)
    assert mesh["FUV"].shape == mesh["F"].shape
    assert mesh["UV"].min() >= 0 and mesh["UV"].max() <= 1
    # every output corner (position, uv) pair exists in the source file: UVs belong to their corners
    ref = _obj_corners(folder / "james.obj")
    got = set(zip(map(tuple, mesh["V"][mesh["F"]].reshape(-1, 3).tolist()),
                  map(tuple, mesh["UV"][mesh["FUV"]].reshape(-1, 2).tolist())))
    assert got <= ref
    m = read_metrics(out)
    assert m["vertices_in"] == 6393 and m["faces_in"] == 12228 and m["uv_count"] > m["vertices_out"]
    assert m["repairs"]["debris_faces"] < 100
    assert max(m["hint_surface_distance_mm"].values()) < 2.0


def test_real_ict_neutral(extra_scan, tmp_path):
    folder = extra_scan("ict_neutral")
    out = tmp_path / "ict"
    assert ingest(folder, out) == 0
    mesh = load_mesh(out / "mesh.npz")
    assert len(mesh["F"]) == 300000 and len(mesh["V"]) == 151590
    m = read_metrics(out)
    assert max(m["hint_surface_distance_mm"].values()) < 3.0      # hints are 2 mm off the opening centre
    gt = json.loads((folder / "ground_truth.json").read_text())
    assert gt["eyes"]["left"]["eyeball_sphere"]["center_mm"][0] > 0  # subject's left at +X, as our frame
    scan = json.loads((out / "scan.json").read_text())
    assert scan["eyes"]["left"]["hint"][0] > 0 > scan["eyes"]["right"]["hint"][0]


def test_synthetic_head_if_present(tmp_path):
    folder = ROOT / "raw_scans" / "synthetic_head"
    if not (folder / "scan.yaml").exists():
        pytest.skip("raw_scans/synthetic_head not generated yet")
    out = tmp_path / "syn"
    assert ingest(folder, out) == 0
    mesh = load_mesh(out / "mesh.npz")
    assert len(mesh["F"]) > 0
    scan = json.loads((out / "scan.json").read_text())
    if scan["texture"]:
        assert "UV" in mesh and (out / "texture.png").exists()


# ---------------------------------------------------------------------------- library pieces

def test_closest_point_matches_dense_sampling():
    from pipeline.ingest.repair import closest_point_on_triangles, point_surface_distance

    rng = np.random.default_rng(3)
    A, B, C = (rng.normal(0, 1, (200, 3)) for _ in range(3))
    for p in rng.normal(0, 2, (5, 3)):
        cp = closest_point_on_triangles(A, B, C, p)
        # brute force: dense barycentric samples can only be farther
        w = rng.dirichlet([1, 1, 1], 4000)
        w = np.vstack([w, np.eye(3)])
        S = w[None, :, 0, None] * A[:, None] + w[None, :, 1, None] * B[:, None] + w[None, :, 2, None] * C[:, None]
        brute = np.linalg.norm(S - p, axis=2).min(axis=1)
        got = np.linalg.norm(cp - p, axis=1)
        assert np.all(got <= brute + 1e-9) and np.all(got >= brute - 0.05)
    from trimesh.triangles import closest_point

    V, F, hints = head_mesh(3)
    for p in [hints["left"], hints["right"], np.array([0.0, 0, 0]), np.array([10.0, 300, -40])]:
        ref = float(np.linalg.norm(closest_point(V[F], np.repeat(p[None], len(F), 0)) - p, axis=1).min())
        assert point_surface_distance(V, F, p) == pytest.approx(ref, abs=1e-9)
    assert point_surface_distance(V, F, V[7]) == 0.0


@pytest.mark.parametrize("endian", ["<", ">"])
def test_binary_ply_mixed_polygons_and_big_endian(tmp_path, endian):
    """Binary PLY with triangles and quads mixed (row-by-row path) and big-endian data."""
    V, F, hints = head_mesh(3)
    # glue pairs of triangles that share an edge into quads? simpler: add a far-away quad (debris)
    quad_v = np.array([[0, -160, 0], [5, -160, 0], [5, -155, 0], [0, -155, 0]], float)
    Vall = np.vstack([V, quad_v])
    rows = [np.array([3, *f]) for f in F] + [np.array([4, *(len(V) + np.arange(4))])]
    folder = tmp_path / "mixed"
    folder.mkdir()
    e = "binary_little_endian" if endian == "<" else "binary_big_endian"
    head = (f"ply\nformat {e} 1.0\ncomment made by a test\nelement vertex {len(Vall)}\nproperty double x\n"
            f"property double y\nproperty double z\nelement face {len(rows)}\n"
            "property list uchar uint vertex_indices\nend_header\n")
    body = Vall.astype(endian + "f8").tobytes()
    body += b"".join(np.uint8(r[0]).tobytes() + r[1:].astype(endian + "u4").tobytes() for r in rows)
    (folder / "scan.ply").write_bytes(head.encode() + body)
    write_sidecar(folder, hints)
    out = tmp_path / "out"
    assert ingest(folder, out) == 0
    m = read_metrics(out)
    assert m["faces_in"] == len(F) + 2 and m["polygons_triangulated"] == 1
    assert m["repairs"]["debris_faces"] == 2
    mesh = load_mesh(out / "mesh.npz")
    np.testing.assert_array_equal(mesh["V"], V)  # float64 stored: exact


def _obj_variants():
    V, F, _ = head_mesh(2)
    uv = sphere_uv(V)
    v = [f"v {x!r} {y!r} {z!r}" for x, y, z in V.tolist()]
    vt = [f"vt {a!r} {b!r}" for a, b in uv.tolist()]
    vn = ["vn 0 0 1"]
    yield "plain", v + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F], True
    yield "v/vt", ["mtllib m.mtl"] + v + vt + ["usemtl skin"] + [
        f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in F], True
    yield "v//vn crlf", [ln + "\r" for ln in v + vn + [f"f {a + 1}//1 {b + 1}//1 {c + 1}//1" for a, b, c in F]], True
    yield "v/vt/vn groups", v[:20] + ["g head", "# c"] + v[20:] + vt + vn + [
        f"f {a + 1}/{a + 1}/1 {b + 1}/{b + 1}/1 {c + 1}/{c + 1}/1" for a, b, c in F], True
    quads = [f"f {a + 1} {b + 1} {c + 1} {c + 1}" for a, b, c in F]
    yield "quads", v + quads, True
    yield "mixed", v + quads[:5] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F[5:]], True
    yield "mixed v/vt pentagons", v + vt + [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1} {a + 1}/1 {b + 1}/2"
                                            for a, b, c in F[:7]] + [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}"
                                                                     for a, b, c in F[7:]], True
    yield "negative", v + [f"f {a - len(V)} {b - len(V)} {c - len(V)}" for a, b, c in F], True
    yield "negative interleaved", v[:10] + ["f -1 -2 -3"] + v[10:] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F], False
    yield "index 0", v + ["f 0 1 2"] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F], False
    yield "trailing comment", v + [f"f {a + 1} {b + 1} {c + 1} # x" for a, b, c in F], False  # load_obj cuts them first


@pytest.mark.parametrize("name,lines,fast", list(_obj_variants()), ids=[v[0] for v in _obj_variants()])
def test_obj_fast_parser_agrees_with_line_parser(name, lines, fast):
    from pipeline.io.formats.common import Limits
    from pipeline.io.formats.obj import _obj_fast, _obj_slow

    raw = ("\n".join(lines) + "\n").encode()
    got = _obj_fast(raw, Path("x.obj"), Limits())
    assert (got is not None) == fast
    if got is None:
        return
    ref = _obj_slow(raw, Path("x.obj"), Limits())
    for a, b in zip(got, ref):
        if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
            np.testing.assert_array_equal(a, b)
        else:
            assert a == b


def test_edge_stats_counts():
    from pipeline.ingest.repair import edge_stats

    F = np.array([[0, 1, 2], [0, 2, 3]])                  # two triangles, consistent, 4 boundary edges
    assert edge_stats(F, 4) == {"edges": 5, "boundary": 4, "non_manifold": 0, "inconsistent_winding": 0}
    F = np.array([[0, 1, 2], [0, 3, 2]])                  # second flipped: shared edge same direction
    assert edge_stats(F, 4)["inconsistent_winding"] == 1
    F = np.array([[0, 1, 2], [0, 2, 3], [2, 0, 4]])       # three faces on edge 0-2
    assert edge_stats(F, 5)["non_manifold"] == 1


def test_ascii_ply_mixed_polygons(tmp_path):
    V, F, hints = head_mesh(3)
    quad_v = np.array([[0, -160, 0], [5, -160, 0], [5, -155, 0], [0, -155, 0]], float)
    Vall = np.vstack([V, quad_v])
    folder = tmp_path / "ascii"
    folder.mkdir()
    head = (f"ply\r\nformat ascii 1.0\r\nelement vertex {len(Vall)}\r\nproperty double x\r\nproperty double y\r\n"
            f"property double z\r\nelement face {len(F) + 1}\r\nproperty list uchar int vertex_indices\r\nend_header\r\n")
    rows = [f"{x!r} {y!r} {z!r}" for x, y, z in Vall.tolist()]
    rows += [f"3 {a} {b} {c}" for a, b, c in F] + [f"4 {len(V)} {len(V) + 1} {len(V) + 2} {len(V) + 3}"]
    (folder / "scan.ply").write_text(head + "\r\n".join(rows) + "\r\n")
    write_sidecar(folder, hints)
    out = tmp_path / "out"
    assert ingest(folder, out) == 0
    m = read_metrics(out)
    assert m["polygons_triangulated"] == 1 and m["repairs"]["debris_faces"] == 2
    np.testing.assert_array_equal(load_mesh(out / "mesh.npz")["V"], V)


def test_ply_texturefile_comment(tmp_path):
    folder = tmp_path / "texcomment"
    folder.mkdir()
    V, F, hints = head_mesh(3)
    write_ply(folder / "scan.ply", V, F, uv=sphere_uv(V), uv_names=("u", "v"), header_extra="comment TextureFile tex.jpg")
    from PIL import Image
    Image.new("RGB", (40, 20), (10, 200, 30)).save(folder / "tex.jpg")
    write_sidecar(folder, hints)
    out = tmp_path / "out"
    assert ingest(folder, out) == 0
    with Image.open(out / "texture.png") as img:
        assert img.size == (40, 20) and img.format == "PNG"
    assert "tex.jpg" in read_metrics(out)["files_read"]


def test_synthetic_head_generator_output(tmp_path):
    """The generator (pipeline/synthetic_head/) writes a folder ingest accepts as is."""
    from pipeline import synthetic_head as synthetic

    head = synthetic.make_synthetic_head(seed=3, target_triangles=20000, texture_size=128, noise_mm=0.0)
    folder = tmp_path / "synthetic_head"
    folder.mkdir()
    synthetic.write_scan_folder(head, folder)
    out = tmp_path / "out"
    assert ingest(folder, out) == 0
    mesh = load_mesh(out / "mesh.npz")
    np.testing.assert_allclose(mesh["V"], head.V.astype(np.float32), atol=1e-9)   # head frame mm already
    np.testing.assert_array_equal(mesh["F"], head.F)
    np.testing.assert_allclose(mesh["UV"][mesh["FUV"]], head.UV[head.F].astype(np.float32), atol=1e-7)
    m = read_metrics(out)
    assert all(v == 0 for k, v in m["repairs"].items() if k != "components")
    assert m["edges"]["inconsistent_winding"] == 0 and m["flipped_winding"] is False
    assert max(m["hint_surface_distance_mm"].values()) < 6.0
    assert m["texture_size"] == [128, 128]
