#!/usr/bin/env python3
"""Compare Strata's volume mesher with VTK's vtkFlyingEdges3D.

Builds the two 256^3 u8 benchmark volumes of terrain/benches/mesh_volume.rs
(same integer formulas, so the same bytes: compare the printed FNV-1a hashes
with the bench's), writes them as raw files, times vtkFlyingEdges3D on one
thread (Sequential SMP backend) at iso 127.5, then runs the release
`strata-admin mesh --stats` with 1 and 2 threads on the same files and prints
cells/s for each and the ratio to VTK.

Usage: python3 scripts/vtk_flying_edges.py [--n 256] [--repeat 7] [--workdir DIR]
       [--bin PATH/strata-admin] [--no-build]
Needs: pip install vtk numpy
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

M32 = 0xFFFFFFFF
ISO = 127.5


def lattice(ix, iy, iz, seed):
    """Integer lattice hash to 0..255 (uint64 arrays, 32-bit wrapping)."""
    h = (ix * 0x27D4EB2D + iy * 0x165667B1 + iz * 0x9E3779B1 + seed * 0x85EBCA77) & M32
    h ^= h >> 15
    h = (h * 0x2C1B3C6D) & M32
    h ^= h >> 12
    h = (h * 0x297A2D39) & M32
    h ^= h >> 15
    return h & 255


def smooth(f, c):
    return f * f * (3 * c - 2 * f) // (c * c)


def noise2(x, z, c, seed):
    ix, iz = x // c, z // c
    wx, wz = smooth(x % c, c), smooth(z % c, c)
    v = (lattice(ix, iz, 0, seed) * (c - wx) * (c - wz)
         + lattice(ix + 1, iz, 0, seed) * wx * (c - wz)
         + lattice(ix, iz + 1, 0, seed) * (c - wx) * wz
         + lattice(ix + 1, iz + 1, 0, seed) * wx * wz)
    return v // (c * c)


def noise3(x, y, z, c, seed):
    ix, iy, iz = x // c, y // c, z // c
    w = [smooth(x % c, c), smooth(y % c, c), smooth(z % c, c)]
    v = np.zeros(np.broadcast(x, y, z).shape, dtype=np.uint64)
    for corner in range(8):
        b = [corner & 1, (corner >> 1) & 1, corner >> 2]
        weight = np.uint64(1)
        for a in range(3):
            weight = weight * (w[a] if b[a] else c - w[a])
        v += lattice(ix + np.uint64(b[0]), iy + np.uint64(b[1]), iz + np.uint64(b[2]), seed) * weight
    return v // (c * c * c)


def terrain_volume(n):
    """Layered value-noise height field plus a 3D noise term (overhangs)."""
    u = np.uint64
    x = np.arange(n, dtype=np.uint64)[None, :]
    z = np.arange(n, dtype=np.uint64)[:, None]
    h = (noise2(x, z, u(64), u(1)) * u(120) + noise2(x, z, u(16), u(2)) * u(40)
         + noise2(x, z, u(4), u(3)) * u(10))
    height = (n * 40 // 256) + (h // u(255) * u(n) // u(256)).astype(np.int64)  # [z, x]
    vol = np.empty((n, n, n), dtype=np.uint8)  # [z, y, x]
    ys = np.arange(n, dtype=np.uint64)[:, None]
    xs = np.arange(n, dtype=np.uint64)[None, :]
    for zi in range(n):
        n3 = noise3(xs, ys, u(zi), u(32), u(4)).astype(np.int64)
        d = 10 * (height[zi][None, :] - ys.astype(np.int64)) + n3
        vol[zi] = np.clip(d, 0, 255).astype(np.uint8)
    return vol


def sphere_volume(n):
    """Ball of radius 100*n/256 in the middle, density falling 4 per voxel."""
    r32 = 3200 * n // 256
    c = n - 1
    a = (2 * np.arange(n, dtype=np.int64) - c) ** 2
    d2 = a[:, None, None] + a[None, :, None] + a[None, None, :]
    t = 256 * d2
    s = np.floor(np.sqrt(t.astype(np.float64))).astype(np.int64)
    # Exact integer square root (floor), whatever the float rounding.
    s -= (s * s > t)
    s += ((s + 1) * (s + 1) <= t)
    return np.clip(128 + ((r32 - s) >> 3), 0, 255).astype(np.uint8)


def fnv1a(data):
    # Sequential by nature: about 10 s per 256^3 volume in pure Python.
    h = 0xCBF29CE484222325
    for b in data.tobytes():
        h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


def vtk_time(vol, repeat, normals):
    import vtk
    from vtk.util import numpy_support

    vtk.vtkSMPTools.SetBackend("Sequential")
    n = vol.shape[0]
    img = vtk.vtkImageData()
    img.SetDimensions(n, n, n)
    arr = numpy_support.numpy_to_vtk(vol.ravel(order="C"), deep=True, array_type=vtk.VTK_UNSIGNED_CHAR)
    img.GetPointData().SetScalars(arr)
    times, tris, verts = [], 0, 0
    for _ in range(repeat):
        fe = vtk.vtkFlyingEdges3D()
        fe.SetInputData(img)
        fe.SetValue(0, ISO)
        fe.SetComputeNormals(normals)
        fe.SetComputeGradients(False)
        fe.SetComputeScalars(False)
        t0 = time.perf_counter()
        fe.Update()
        times.append(time.perf_counter() - t0)
        out = fe.GetOutput()
        tris, verts = out.GetNumberOfCells(), out.GetNumberOfPoints()
    return min(times), statistics.median(times), verts, tris


def strata_time(binary, path, n, threads, repeat):
    times, stats = [], None
    for _ in range(repeat):
        cmd = [str(binary), "mesh", "--volume", str(path), "--dims", str(n), str(n), str(n),
               "--threads", str(threads), "--stats"]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True)
        stats = json.loads(out.stdout)
        times.append(stats["mesh_seconds"])
    return min(times), statistics.median(times), stats


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--workdir", type=Path, default=None)
    ap.add_argument("--bin", type=Path, default=None)
    ap.add_argument("--no-build", action="store_true")
    ap.add_argument("--hash", action="store_true", help="print FNV-1a of each volume (slow)")
    args = ap.parse_args()
    root = Path(__file__).resolve().parent.parent
    target = Path(os.environ.get("CARGO_TARGET_DIR", root / "target"))
    binary = args.bin or target / "release" / "strata-admin"
    if not args.no_build:
        subprocess.run(["cargo", "build", "--release", "-q", "-p", "strata-server", "--bin", "strata-admin"],
                       cwd=root, check=True)
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="strata-vtk-"))
    workdir.mkdir(parents=True, exist_ok=True)

    n = args.n
    cells = (n - 1) ** 3
    rows = []
    for name, make in [("terrain", terrain_volume), ("sphere", sphere_volume)]:
        vol = make(n)
        path = workdir / f"{name}_{n}.raw"
        path.write_bytes(vol.tobytes(order="C"))
        if args.hash:
            print(f"{name}: fnv1a {fnv1a(vol):016x}", flush=True)
        best, med, verts, tris = vtk_time(vol, args.repeat, normals=True)
        best_nn, med_nn, _, _ = vtk_time(vol, args.repeat, normals=False)
        rows.append((name, "vtkFlyingEdges3D x1 (normals)", best, med, verts, tris))
        rows.append((name, "vtkFlyingEdges3D x1 (no normals)", best_nn, med_nn, verts, tris))
        for threads in (1, 2):
            sb, sm, st = strata_time(binary, path, n, threads, args.repeat)
            assert st["cells"] == cells, st
            rows.append((name, f"strata-admin x{threads}", sb, sm, st["vertices"], st["triangles"]))

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"\n{n}^3 u8 volumes, iso {ISO}, {cells} cells, best of {args.repeat} (median in brackets), "
          f"{os.cpu_count()} cores, load average {load:.1f}")
    print(f"{'volume':8} {'mesher':34} {'ms':>16} {'M cells/s':>10} {'vs VTK':>7} {'verts':>9} {'tris':>9}")
    for name, mesher, best, med, verts, tris in rows:
        vtk_best = next(r[2] for r in rows if r[0] == name)
        print(f"{name:8} {mesher:34} {best * 1e3:7.1f} ({med * 1e3:6.1f}) {cells / best / 1e6:10.0f} "
              f"{vtk_best / best:6.2f}x {verts:9d} {tris:9d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
