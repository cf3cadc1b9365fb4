#!/usr/bin/env python3
"""Writes rd-mini's foot meshes as a CAD exporter would: binary STL in millimetres, each in its
part's own frame (origin on the ankle-roll axis, the sole 38 mm below it and the toe 10 mm ahead
of centre), so the MJCF needs a mesh scale of 0.001 and the soles are offset from their bodies.

The sole is a plate with rounded corners (a convex prism, which MuJoCo collides as its own hull),
100 x 56 x 9 mm; the left foot leans 4 mm outwards (+y), the right foot mirrors it. Deterministic:
the same bytes on every run (tests compare them).

    scripts/gen_mini_feet.py robots/mini/meshes
"""

import math
import struct
import sys
from pathlib import Path

LENGTH, WIDTH, THICK = 100.0, 56.0, 9.0  # mm
CORNER = 9.0  # corner radius, mm
SEGMENTS = 6  # per quarter circle
SOLE_Z = -38.0  # sole below the ankle axis, mm
TOE_AHEAD = 10.0  # centre of the plate ahead of the ankle, mm
OUTWARD = 4.0  # the plate's centre outwards of the ankle, mm


def outline(side):
    """Counter-clockwise outline (seen from above) of the sole, mm."""
    cx, cy = TOE_AHEAD, side * OUTWARD
    hx, hy = LENGTH / 2 - CORNER, WIDTH / 2 - CORNER
    points = []
    for corner, (sx, sy) in enumerate([(1, 1), (-1, 1), (-1, -1), (1, -1)]):
        start = corner * math.pi / 2
        for k in range(SEGMENTS + 1):
            a = start + k * (math.pi / 2) / SEGMENTS
            points.append((cx + sx * hx + CORNER * math.cos(a), cy + sy * hy + CORNER * math.sin(a)))
    return points


def prism(points, z0, z1):
    """Triangles of a closed prism over a convex outline."""
    n = len(points)
    tris = []
    cx = sum(p[0] for p in points) / n
    cy = sum(p[1] for p in points) / n
    for i in range(n):
        a, b = points[i], points[(i + 1) % n]
        # Top (+z) and bottom (-z) fans around the centre.
        tris.append(((cx, cy, z1), (a[0], a[1], z1), (b[0], b[1], z1)))
        tris.append(((cx, cy, z0), (b[0], b[1], z0), (a[0], a[1], z0)))
        # Side quad, outward.
        tris.append(((a[0], a[1], z0), (b[0], b[1], z0), (b[0], b[1], z1)))
        tris.append(((a[0], a[1], z0), (b[0], b[1], z1), (a[0], a[1], z1)))
    return tris


def normal(t):
    (ax, ay, az), (bx, by, bz), (cx, cy, cz) = t
    ux, uy, uz = bx - ax, by - ay, bz - az
    vx, vy, vz = cx - ax, cy - ay, cz - az
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    length = math.sqrt(nx * nx + ny * ny + nz * nz) or 1.0
    return nx / length, ny / length, nz / length


def write_stl(path, name, tris):
    header = f"robodeploy rd-mini {name} (scripts/gen_mini_feet.py), mm".encode()[:80].ljust(80, b" ")
    with open(path, "wb") as f:
        f.write(header)
        f.write(struct.pack("<I", len(tris)))
        for t in tris:
            f.write(struct.pack("<3f", *normal(t)))
            for v in t:
                f.write(struct.pack("<3f", *v))
            f.write(struct.pack("<H", 0))


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    for name, side in [("left_foot", 1), ("right_foot", -1)]:
        write_stl(out / f"{name}.stl", name, prism(outline(side), SOLE_Z, SOLE_Z + THICK))
        print(f"wrote {out / (name + '.stl')}")


if __name__ == "__main__":
    main()
