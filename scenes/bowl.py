"""Writes scenes/bowl.obj: a closed surface of a bowl (a spherical cap shell), the input of
scenes/sound-bowl.toml, which voxel-meshes it.

Outer radius 8 cm, wall 8 mm, the cap from the bottom pole up to 70 degrees from it
(so 16 cm across at most, 5.3 cm deep), with a flat ring joining the two caps at the
rim. Outward normals (counter-clockwise seen from outside). Run: python3 scenes/bowl.py
"""
import math
import os

R, T, TOP = 0.08, 0.008, math.radians(70.0)
N_THETA, N_PHI = 24, 64

verts, faces = [], []


def cap(radius):
    """Rings of the cap of `radius` from the pole; returns (pole index, ring indices)."""
    pole = len(verts)
    verts.append((0.0, -radius, 0.0))
    rings = []
    for i in range(1, N_THETA + 1):
        th = TOP * i / N_THETA
        ring = []
        for j in range(N_PHI):
            ph = 2.0 * math.pi * j / N_PHI
            ring.append(len(verts))
            verts.append((radius * math.sin(th) * math.cos(ph), -radius * math.cos(th),
                          radius * math.sin(th) * math.sin(ph)))
        rings.append(ring)
    return pole, rings


def quads(pole, rings, outward):
    def tri(a, b, c):
        faces.append((a, c, b) if outward else (a, b, c))
    for j in range(N_PHI):
        k = (j + 1) % N_PHI
        tri(pole, rings[0][k], rings[0][j])
    for r0, r1 in zip(rings, rings[1:]):
        for j in range(N_PHI):
            k = (j + 1) % N_PHI
            tri(r0[j], r0[k], r1[k])
            tri(r0[j], r1[k], r1[j])


outer = cap(R)
inner = cap(R - T)
quads(*outer, outward=True)
quads(*inner, outward=False)
# The rim: from the outer top ring to the inner one.
o, i = outer[1][-1], inner[1][-1]
for j in range(N_PHI):
    k = (j + 1) % N_PHI
    faces.append((o[j], i[k], o[k]))
    faces.append((o[j], i[j], i[k]))

path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "bowl.obj")
with open(path, "w") as f:
    f.write("# scenes/bowl.py: a bowl, outer radius 0.08 m, wall 0.008 m, cap to 70 degrees\n")
    for v in verts:
        f.write("v %.6f %.6f %.6f\n" % v)
    for a, b, c in faces:
        f.write("f %d %d %d\n" % (a + 1, b + 1, c + 1))
