"""Rigid objects made of planar textured faces.

Object-local coordinates follow the camera convention (x right, y down, z
away from the viewer), so "up" is -y and the front face looks along -z.
Each face is a rectangle ``origin + s * edge_s + t * edge_t`` with
``s, t`` in [0, 1] (edges orthogonal), optionally cut to its inscribed disc.
"""

from __future__ import annotations

import dataclasses

from dataclasses import dataclass

import numpy as np

from ..geometry import axis_angle_to_matrix, make_transform
from ._textures import TEXELS_PER_UNIT, face_texture

#: Spacing in world units of the surface samples returned as ``part_points``.
POINT_SPACING = 0.05


@dataclass(frozen=True)
class Face:
    """One planar face.

    Attributes
    ----------
    origin, edge_s, edge_t : (3,) float64
        Corner at ``s = t = 0`` and the two orthogonal edge vectors.
    normals : (2, 3) float64
        Outward shading normals at ``s = 0`` and ``s = 1`` (equal on flat
        faces; they differ on the facets of a smooth cylinder).
    texture : (Ht, Wt, 3) float32
        Colours in [0, 1].
    window : (4,) float64
        ``s0, s1, t0, t1``: the part of ``texture`` this face shows, so several
        facets can share one texture.
    disk : bool
        Only the disc inscribed in the rectangle is solid (cylinder caps).
    """

    origin: np.ndarray
    edge_s: np.ndarray
    edge_t: np.ndarray
    normals: np.ndarray
    texture: np.ndarray
    window: np.ndarray
    disk: bool = False

    @property
    def normal(self) -> np.ndarray:
        """(3,) outward geometric normal."""
        n = np.cross(self.edge_s, self.edge_t)
        n /= np.linalg.norm(n)
        return n if n @ (self.normals[0] + self.normals[1]) > 0 else -n

    def transformed(self, m: np.ndarray) -> "Face":
        """The face moved by a rigid transform (4, 4)."""
        r, t = m[:3, :3], m[:3, 3]
        return Face(r @ self.origin + t, r @ self.edge_s, r @ self.edge_t, self.normals @ r.T,
                    self.texture, self.window, self.disk)

    def sample_points(self, spacing: float = POINT_SPACING) -> np.ndarray:
        """Grid of surface points (M, 3), corners and edges included."""
        ns = int(np.ceil(np.linalg.norm(self.edge_s) / spacing)) + 1
        nt = int(np.ceil(np.linalg.norm(self.edge_t) / spacing)) + 1
        s, t = np.meshgrid(np.linspace(0, 1, ns), np.linspace(0, 1, nt), indexing="ij")
        s, t = s.ravel(), t.ravel()
        if self.disk:
            keep = (2 * s - 1) ** 2 + (2 * t - 1) ** 2 <= 1
            s, t = s[keep], t[keep]
        return self.origin + s[:, None] * self.edge_s + t[:, None] * self.edge_t


@dataclass(frozen=True)
class Shape:
    """An object: parts (part 0 the body, the largest but for a screen's stand), each a tuple of faces, in
    object-local coordinates.

    ``hinge`` is ``(point, direction)``, two (3,) arrays: the line about which
    part 1 turns relative to part 0, with positive angles opening it; ``slide``
    a (3,) unit direction along which part 1 slides out of part 0; None where
    the object has no such joint.
    """

    parts: tuple[tuple[Face, ...], ...]
    hinge: tuple[np.ndarray, np.ndarray] | None = None
    slide: np.ndarray | None = None

    def transformed(self, m: np.ndarray) -> "Shape":
        """All parts moved by one rigid transform (4, 4)."""
        hinge = None
        if self.hinge is not None:
            hinge = (m[:3, :3] @ self.hinge[0] + m[:3, 3], m[:3, :3] @ self.hinge[1])
        slide = None if self.slide is None else m[:3, :3] @ self.slide
        return Shape(tuple(tuple(f.transformed(m) for f in part) for part in self.parts), hinge, slide)

    def plain(self) -> "Shape":
        """The shape with every face one colour, its texture's mean (shading alone varies it)."""
        return Shape(tuple(tuple(dataclasses.replace(f, texture=np.broadcast_to(
            f.texture.mean(axis=(0, 1)), f.texture.shape).astype(np.float32)) for f in part) for part in self.parts),
            self.hinge, self.slide)

    def part_points(self) -> list[np.ndarray]:
        """Surface samples per part, a list of (M_k, 3) float64."""
        return [np.concatenate([f.sample_points() for f in part]) for part in self.parts]

    def bounding_radius(self) -> float:
        """Largest distance of a surface point from the local origin."""
        return float(max(np.linalg.norm(p, axis=1).max() for p in self.part_points()))


def _texture_shape(width: float, height: float) -> tuple[int, int]:
    return max(int(round(height * TEXELS_PER_UNIT)), 8), max(int(round(width * TEXELS_PER_UNIT)), 8)


def _flat_face(origin, edge_s, edge_t, outward, texture) -> Face:
    n = np.asarray(outward, dtype=np.float64)
    return Face(np.asarray(origin, dtype=np.float64), np.asarray(edge_s, dtype=np.float64),
                np.asarray(edge_t, dtype=np.float64), np.stack([n, n]), texture, np.array([0.0, 1.0, 0.0, 1.0]))


def _hues(rng: np.random.Generator, count: int, target: bool) -> np.ndarray:
    """Distinct hues (count,) in turns: spread over the wheel, or over red-yellow for the target look."""
    spread = (rng.random() + 0.618034 * np.arange(count)) % 1.0
    return (0.96 + 0.14 * spread) % 1.0 if target else spread


def _box_faces(centre, half, hues, rng: np.random.Generator, target: bool) -> tuple[Face, ...]:
    """Six faces of an axis-aligned box; texture ``s`` runs rightwards and ``t`` downwards when seen from outside."""
    c = np.asarray(centre, dtype=np.float64)
    a, b, d = half
    specs = [  # origin offset, edge_s, edge_t, outward normal
        ((-a, -b, -d), (2 * a, 0, 0), (0, 2 * b, 0), (0, 0, -1)),   # front
        ((a, -b, d), (-2 * a, 0, 0), (0, 2 * b, 0), (0, 0, 1)),     # back
        ((-a, -b, d), (0, 0, -2 * d), (0, 2 * b, 0), (-1, 0, 0)),   # left
        ((a, -b, -d), (0, 0, 2 * d), (0, 2 * b, 0), (1, 0, 0)),     # right
        ((-a, -b, d), (2 * a, 0, 0), (0, 0, -2 * d), (0, -1, 0)),   # top
        ((-a, b, -d), (2 * a, 0, 0), (0, 0, 2 * d), (0, 1, 0)),     # bottom
    ]
    faces = []
    for (off, es, et, n), hue in zip(specs, hues):
        tex = face_texture(rng, _texture_shape(np.linalg.norm(es), np.linalg.norm(et)), hue,
                           saturation=(0.7 if target else 0.55) * rng.uniform(0.85, 1.15),
                           value=0.95 if target else rng.uniform(0.7, 0.95), checker=target)
        faces.append(_flat_face(c + off, es, et, n, tex))
    return tuple(faces)


def make_box(geom: np.random.Generator, tex: np.random.Generator, target: bool = False) -> Shape:
    """A box about 1.7 x 1.05 x 1.05 units (size varies with ``geom``), centred at the origin.

    ``geom`` draws the size, ``tex`` the textures; ``target`` selects the look
    of target images (warm hues, checker cells) over the source look (hues
    all round the wheel, blobs).
    """
    half = 0.5 * np.array([geom.uniform(1.5, 1.9), geom.uniform(0.9, 1.2), geom.uniform(0.9, 1.2)])
    return Shape((_box_faces(np.zeros(3), half, _hues(tex, 6, target), tex, target),))


def make_hinged_box(geom: np.random.Generator, tex: np.random.Generator, target: bool = False) -> Shape:
    """A body box with a thin lid on top, hinged along the lid's bottom back edge.

    Part 0 is the body, part 1 the lid; both have the same footprint. The
    local origin is the centre of the closed object's bounding box. Positive
    hinge angles lift the lid's front edge.
    """
    w, h, d = geom.uniform(1.5, 1.8), geom.uniform(0.75, 0.95), geom.uniform(1.0, 1.2)
    lid = geom.uniform(0.12, 0.16)
    shift = np.array([0.0, lid / 2, 0.0])  # centre the closed object on the origin
    hues = _hues(tex, 12, target)
    body = _box_faces(shift, (w / 2, h / 2, d / 2), hues[:6], tex, target)
    lid_faces = _box_faces(shift + [0.0, -(h + lid) / 2, 0.0], (w / 2, lid / 2, d / 2), hues[6:], tex, target)
    # Rotating by -angle about +x lifts the front (-z) edge, so the axis points along -x.
    hinge_point = shift + np.array([0.0, -h / 2, d / 2])
    return Shape((body, lid_faces), (hinge_point, np.array([-1.0, 0.0, 0.0])))


def make_door(geom: np.random.Generator, tex: np.random.Generator, target: bool = False) -> Shape:
    """A tall cabinet with a door over its front, hinged on its left or right upright edge.

    Part 0 is the cabinet, part 1 the door (a thin slab standing a little proud of the front); positive hinge
    angles swing the door open, towards -z. The local origin is the cabinet's centre.
    """
    w, h, d = geom.uniform(1.0, 1.2), geom.uniform(1.3, 1.6), geom.uniform(0.7, 0.9)
    side = geom.choice([-1.0, 1.0])  # the hinge's side: x = side * w / 2
    thick = 0.05
    hues = _hues(tex, 12, target)
    cabinet = _box_faces(np.zeros(3), (w / 2, h / 2, d / 2), hues[:6], tex, target)
    door = _box_faces([0.0, 0.0, -d / 2 - thick / 2], (0.48 * w, 0.48 * h, thick / 2), hues[6:], tex, target)
    # Turning about +y by a positive angle carries a point on the +x side of the axis towards -z.
    return Shape((cabinet, door), (np.array([side * 0.48 * w, 0.0, -d / 2]), np.array([0.0, -side, 0.0])))


def make_screen(geom: np.random.Generator, tex: np.random.Generator, target: bool = False) -> Shape:
    """A screen on a stand, swivelling about the stand's upright post.

    Part 0 is the stand (a flat base and a post), part 1 the screen (a thin panel in front of the post's top);
    positive hinge angles turn the screen's right edge (+x) towards -z. The local origin is the centre of the
    whole object's bounding box.
    """
    w, sh = geom.uniform(1.4, 1.7), geom.uniform(0.8, 1.0)
    h = sh + geom.uniform(0.45, 0.6)
    base_t, post, panel = 0.08, 0.06, 0.05
    hues = _hues(tex, 18, target)
    base = _box_faces([0.0, h / 2 - base_t / 2, 0.0], (0.3 * w, base_t / 2, 0.3), hues[:6], tex, target)
    post_h = h - base_t - 0.2 * sh
    stand = base + _box_faces([0.0, h / 2 - base_t - post_h / 2, 0.0], (post, post_h / 2, post), hues[6:12], tex,
                              target)
    screen = _box_faces([0.0, -h / 2 + sh / 2, -post - panel / 2], (w / 2, sh / 2, panel / 2), hues[12:], tex,
                        target)
    # Turning about -y (up) by a positive angle carries a point on the +x side towards -z.
    return Shape((stand, screen), (np.zeros(3), np.array([0.0, -1.0, 0.0])))


def make_drawer(geom: np.random.Generator, tex: np.random.Generator, target: bool = False) -> Shape:
    """A cabinet with a drawer in the upper part of its front, sliding out along -z.

    Part 0 is the cabinet, part 1 the drawer (a box whose front stands a little proud of the cabinet's);
    the local origin is the cabinet's centre.
    """
    w, h, d = geom.uniform(1.4, 1.7), geom.uniform(0.9, 1.1), geom.uniform(0.9, 1.1)
    half = np.array([0.4 * w, 0.17 * h, 0.45 * d])
    hues = _hues(tex, 12, target)
    cabinet = _box_faces(np.zeros(3), (w / 2, h / 2, d / 2), hues[:6], tex, target)
    drawer = _box_faces([0.0, -0.2 * h, -d / 2 - 0.02 + half[2]], half, hues[6:], tex, target)
    return Shape((cabinet, drawer), slide=np.array([0.0, 0.0, -1.0]))


def _revolved(profile: np.ndarray, heights: np.ndarray, hues: np.ndarray, tex: np.random.Generator,
              target: bool, facets: int) -> tuple[Face, ...]:
    """Upright slabs (one per radius in ``profile`` (S,), edges at ``heights`` (S+1,), top to bottom):
    ``facets`` side facets with smooth shading, one side texture wrapped once round all of them (seam at
    the back, +z), and disc caps on every slab, hidden where a wider neighbour covers them."""
    height = float(heights[-1] - heights[0])
    r_max = float(profile.max())
    side_tex = face_texture(tex, _texture_shape(2 * np.pi * r_max, height), hues[0], saturation=0.7, value=0.95,
                            checker=target)
    phi = np.linspace(-np.pi, np.pi, facets + 1)  # angle 0 faces the viewer (-z)
    normals = np.stack([np.sin(phi), np.zeros_like(phi), -np.cos(phi)], axis=1)
    faces = []
    for k, r in enumerate(profile):
        y0, y1 = heights[k], heights[k + 1]
        rim = np.stack([r * np.sin(phi), np.full_like(phi, y0), -r * np.cos(phi)], axis=1)
        t0, t1 = (y0 - heights[0]) / height, (y1 - heights[0]) / height
        faces += [Face(rim[i], rim[i + 1] - rim[i], np.array([0.0, y1 - y0, 0.0]), normals[i:i + 2], side_tex,
                       np.array([i / facets, (i + 1) / facets, t0, t1])) for i in range(facets)]
    cap_textures = [face_texture(tex, _texture_shape(2 * r_max, 2 * r_max), hue, saturation=0.7, value=0.95,
                                 checker=target) for hue in hues[1:3]]
    for k, r in enumerate(profile):
        for y, cap_tex in ((heights[k], cap_textures[0]), (heights[k + 1], cap_textures[1])):
            up = np.sign(y - 0.5 * (heights[k] + heights[k + 1]))
            n = np.array([0.0, up, 0.0])
            faces.append(Face(np.array([-r, y, r * up]), np.array([2 * r, 0.0, 0.0]), np.array([0.0, 0.0, -2 * r * up]),
                              np.stack([n, n]), cap_tex, np.array([0.0, 1.0, 0.0, 1.0]), disk=True))
    return tuple(faces)


def make_cylinder(geom: np.random.Generator, tex: np.random.Generator, target: bool = True,
                  facets: int = 48) -> Shape:
    """A squat upright can: ``facets`` side facets with smooth shading, plus disc caps.

    The side texture wraps once around, its seam at the back (+z).
    """
    r, height = geom.uniform(0.55, 0.65), geom.uniform(1.0, 1.2)
    hues = _hues(tex, 3, target)
    return Shape((_revolved(np.array([r]), np.array([-height / 2, height / 2]), hues, tex, target, facets),))


def make_vase(geom: np.random.Generator, tex: np.random.Generator, target: bool = True, facets: int = 48,
              slabs: int = 24) -> Shape:
    """An upright vase: a surface of revolution (a bulging belly, a narrow neck, a flared lip) from thin slabs."""
    height = geom.uniform(1.6, 1.9)
    belly, neck, lip = geom.uniform(0.5, 0.6), geom.uniform(0.2, 0.26), geom.uniform(0.3, 0.36)
    t = (np.arange(slabs) + 0.5) / slabs  # 0 at the top
    profile = (lip + (neck - lip) * np.clip(t / 0.15, 0, 1)  # lip to neck
               + (belly - neck) * np.sin(np.pi * np.clip((t - 0.15) / 0.85, 0, 1)) ** 0.8)  # the belly
    profile = np.maximum(profile, 0.6 * neck)
    heights = np.linspace(-height / 2, height / 2, slabs + 1)
    return Shape((_revolved(profile, heights, _hues(tex, 3, target), tex, target, facets),))


def make_car(geom: np.random.Generator, tex: np.random.Generator, target: bool = True) -> Shape:
    """A car-like shape, mirror-symmetric about its long vertical mid-plane: a body, a cabin set back on it and
    four wheels, about 2 units long; its front towards -x."""
    length, width, body = geom.uniform(1.8, 2.1), geom.uniform(0.8, 0.95), geom.uniform(0.4, 0.5)
    cabin_length, cabin = geom.uniform(0.9, 1.1), geom.uniform(0.35, 0.42)
    wheel, tyre = geom.uniform(0.2, 0.24), 0.12
    hues = _hues(tex, 12, target)
    # y points down: the body's underside sits a wheel's radius above the ground, the cabin on the body.
    floor = 0.5 * (body + cabin) - 0.5 * wheel  # centres the whole car on the origin, roughly
    body_faces = _box_faces([0.0, floor - 0.5 * body, 0.0], 0.5 * np.array([length, body, width]), hues[:6], tex,
                            target)
    cabin_faces = _box_faces([0.15 * length, floor - body - 0.5 * cabin, 0.0],
                             0.5 * np.array([cabin_length, cabin, 0.9 * width]), hues[6:], tex, target)
    wheel_faces = _revolved(np.array([wheel]), np.array([-0.5 * tyre, 0.5 * tyre]), np.full(3, 0.6), tex,
                            target, 24)
    lay = make_transform(axis_angle_to_matrix([np.pi / 2, 0.0, 0.0]), np.zeros(3))  # its axis across the car
    wheels = []
    for x in (-0.32 * length, 0.32 * length):
        for z in (-0.5 * width, 0.5 * width):
            at = make_transform(np.eye(3), [x, floor, z]) @ lay
            wheels += [face.transformed(at) for face in wheel_faces]
    return Shape((body_faces + cabin_faces + tuple(wheels),))


def make_rod(geom: np.random.Generator, tex: np.random.Generator, target: bool = True) -> Shape:
    """A thin upright square bar, about 1/20 as wide as it is tall."""
    height = geom.uniform(1.8, 2.0)
    half = 0.5 * np.array([0.05 * height, height, 0.05 * height])
    return Shape((_box_faces(np.zeros(3), half, _hues(tex, 6, target), tex, target),))
