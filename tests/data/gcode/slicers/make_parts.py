#!/usr/bin/env python3
"""Writes the corpus test parts as binary STL (mm), without CAD; plain Python 3, no packages.

Every part stands on z = 0 and is centred on x = y = 0: CuraEngine puts (0, 0) at the bed centre
(machine_center_is_zero = false), PrusaSlicer and Slic3r centre the part on the bed themselves.

    box20        20 x 20 x 20 mm cube (solid: the slicer makes it walls + sparse infill)
    cyl20        cylinder, diameter 20 mm, 10 mm tall, 128 facets (walls of 0.49 mm chords)
    wedge45      20 mm wide (y) fin whose +x face leans out at 45 degrees: 10 mm foot, 15 mm high,
                 25 mm top (an unsupported 45 degree overhang)
    tower_hole   12 x 12 x 25 mm square tower with a vertical 6 mm hole through it (64 facets)

Usage: make_parts.py OUTDIR
"""

import math
import os
import struct
import sys


def normal(a, b, c):
    u = [b[i] - a[i] for i in range(3)]
    v = [c[i] - a[i] for i in range(3)]
    n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
    length = math.sqrt(sum(x * x for x in n)) or 1.0
    return [x / length for x in n]


def signed_volume(triangles):
    vol = 0.0
    for a, b, c in triangles:
        vol += (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) + a[2] * (b[0] * c[1] - b[1] * c[0])) / 6.0
    return vol


def check_closed(name, triangles):
    """Every edge is used once in each direction: closed, consistently oriented (manifold)."""
    edges = {}
    key = lambda p: tuple(round(x, 6) for x in p)  # noqa: E731
    for tri in triangles:
        for i in range(3):
            e = (key(tri[i]), key(tri[(i + 1) % 3]))
            edges[e] = edges.get(e, 0) + 1
    for (a, b), n in edges.items():
        assert n == 1 and edges.get((b, a)) == 1, f"{name}: edge {a} -> {b} is open or doubled"


def write_stl(path, name, triangles):
    check_closed(name, triangles)
    # Outward normals: a closed mesh with counter-clockwise faces (seen from outside) has positive volume.
    assert signed_volume(triangles) > 0, f"{name}: faces point inwards"
    with open(path, "wb") as f:
        header = f"strand corpus part {name}".encode()
        f.write(header.ljust(80, b" "))
        f.write(struct.pack("<I", len(triangles)))
        for a, b, c in triangles:
            f.write(struct.pack("<3f", *normal(a, b, c)))
            for p in (a, b, c):
                f.write(struct.pack("<3f", *p))
            f.write(struct.pack("<H", 0))


def prism(ring, z0, z1, hole=None):
    """A vertical prism over `ring` (counter-clockwise (x, y) points) from z0 to z1. With `hole`
    (a counter-clockwise ring with as many points, each at the same angle as its ring point), a
    through-hole: the caps are quad strips between the two rings."""
    n = len(ring)
    tris = []
    for i in range(n):
        j = (i + 1) % n
        a, b = ring[i], ring[j]
        tris.append(((a[0], a[1], z0), (b[0], b[1], z0), (b[0], b[1], z1)))
        tris.append(((a[0], a[1], z0), (b[0], b[1], z1), (a[0], a[1], z1)))
    if hole is None:
        cx = sum(p[0] for p in ring) / n
        cy = sum(p[1] for p in ring) / n
        for i in range(n):
            j = (i + 1) % n
            a, b = ring[i], ring[j]
            tris.append(((cx, cy, z1), (a[0], a[1], z1), (b[0], b[1], z1)))
            tris.append(((cx, cy, z0), (b[0], b[1], z0), (a[0], a[1], z0)))
        return tris
    assert len(hole) == n
    for i in range(n):
        j = (i + 1) % n
        a, b = hole[i], hole[j]
        # The hole's wall faces the axis.
        tris.append(((a[0], a[1], z0), (b[0], b[1], z1), (b[0], b[1], z0)))
        tris.append(((a[0], a[1], z0), (a[0], a[1], z1), (b[0], b[1], z1)))
        o0, o1 = ring[i], ring[j]
        # Top cap (facing +z) and bottom cap (facing -z) between the rings.
        tris.append(((a[0], a[1], z1), (o0[0], o0[1], z1), (o1[0], o1[1], z1)))
        tris.append(((a[0], a[1], z1), (o1[0], o1[1], z1), (b[0], b[1], z1)))
        tris.append(((a[0], a[1], z0), (o1[0], o1[1], z0), (o0[0], o0[1], z0)))
        tris.append(((a[0], a[1], z0), (b[0], b[1], z0), (o1[0], o1[1], z0)))
    return tris


def circle(radius, n, phase=0.0):
    return [(radius * math.cos(phase + 2 * math.pi * i / n), radius * math.sin(phase + 2 * math.pi * i / n)) for i in range(n)]


def box20():
    h = 10.0
    return prism([(-h, -h), (h, -h), (h, h), (-h, h)], 0.0, 20.0)


def cyl20():
    return prism(circle(10.0, 128), 0.0, 10.0)


def wedge45():
    # The profile in x-z, extruded along y from -10 to 10; centred on its bounding box in x.
    profile = [(-12.5, 0.0), (-2.5, 0.0), (12.5, 15.0), (-12.5, 15.0)]  # counter-clockwise in x-z
    y0, y1 = -10.0, 10.0
    tris = []
    n = len(profile)
    for i in range(n):
        j = (i + 1) % n
        (ax, az), (bx, bz) = profile[i], profile[j]
        # Side faces: the profile runs counter-clockwise seen from -y, so going a->b the outside is to the right.
        tris.append(((ax, y0, az), (bx, y0, bz), (bx, y1, bz)))
        tris.append(((ax, y0, az), (bx, y1, bz), (ax, y1, az)))
    # End caps (convex profile: a fan). The y0 cap faces -y, the y1 cap +y.
    for i in range(1, n - 1):
        a, b, c = profile[0], profile[i], profile[i + 1]
        tris.append(((a[0], y0, a[1]), (c[0], y0, c[1]), (b[0], y0, b[1])))
        tris.append(((a[0], y1, a[1]), (b[0], y1, b[1]), (c[0], y1, c[1])))
    # Orientation check: the faces must point outwards whichever way the profile's winding reads.
    if signed_volume(tris) < 0:
        tris = [(a, c, b) for a, b, c in tris]
    return tris


def tower_hole():
    n = 64
    half = 6.0
    phase = math.pi / 4  # angle 45 deg is a corner, so all four corners are ring points
    outer = []
    for x, y in circle(1.0, n, phase):
        s = half / max(abs(x), abs(y))
        outer.append((x * s, y * s))
    return prism(outer, 0.0, 25.0, hole=circle(3.0, n, phase))


PARTS = {"box20": box20, "cyl20": cyl20, "wedge45": wedge45, "tower_hole": tower_hole}


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "."
    os.makedirs(out, exist_ok=True)
    for name, make in PARTS.items():
        tris = make()
        write_stl(os.path.join(out, name + ".stl"), name, tris)
        print(f"{name}.stl: {len(tris)} triangles, {signed_volume(tris) / 1000:.3f} cm^3")


if __name__ == "__main__":
    main()
