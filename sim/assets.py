"""Building the bodies of the lab scene: table, containers, obstacles, markers and the tools.

Every builder takes the PyBullet ``client`` id and passes it to each call. Scene objects are
static (mass 0) bodies whose base frame is the centre of their bottom face (the lamp shade:
the centre of its lower rim), so placing one on the table means putting its base at
``(x, y, TABLE_TOP_Z)``. The tools are not separate bodies: ``tool_link_urdf`` returns a URDF
``<link>`` rigidly fixed to ``left_gripper`` that ``sim.world`` splices into Baxter's URDF,
so a tool follows the arm exactly under ``resetJointState`` and under physics.
"""

from __future__ import annotations

import math

import numpy as np

from sim import layout as L
from sim.bullet import p

__all__ = [
    "BUILDERS",
    "COLORS",
    "build_books",
    "build_bowl",
    "build_floor",
    "build_lamp_shade",
    "build_marker",
    "build_paper_towels",
    "build_small_item",
    "build_source",
    "build_table",
    "build_vase",
    "tool_boxes",
    "tool_link_urdf",
]

COLORS = {
    "table": (0.55, 0.40, 0.25, 1.0), "bowl": (0.1, 0.7, 0.2, 1.0), "source": (0.95, 0.85, 0.1, 1.0),
    "white": (0.95, 0.95, 0.95, 1.0), "vase": (0.85, 0.85, 0.9, 1.0), "spoon_tool": (0.1, 0.3, 0.9, 1.0),
    "pitcher": (0.8, 0.8, 0.85, 1.0), "marker": (1.0, 0.2, 0.8, 1.0), "item": (0.5, 0.5, 0.5, 1.0),
    "books": ((0.6, 0.1, 0.1, 1.0), (0.1, 0.2, 0.6, 1.0), (0.2, 0.5, 0.2, 1.0)),
}

def _ring(radius_mid, thickness, y_or_z_range, segments, axis="z", skip=()):
    """Boxes approximating a cylindrical wall around the ``axis`` through the origin.

    ``y_or_z_range``: (lo, hi) along the axis. Returns ``[(centre, half, quat)]``.
    """
    lo, hi = y_or_z_range
    half_t = thickness / 2
    half_w = radius_mid * math.tan(math.pi / segments) * 1.08
    out = []
    for k in range(segments):
        if k in skip:
            continue
        a = 2 * math.pi * k / segments
        if axis == "z":
            c = (radius_mid * math.cos(a), radius_mid * math.sin(a), (lo + hi) / 2)
            q = p.getQuaternionFromEuler((0, 0, a))
            out.append((c, (half_t, half_w, (hi - lo) / 2), q))
        else:  # axis along y; angle measured from +z towards +x
            c = (radius_mid * math.sin(a), (lo + hi) / 2, radius_mid * math.cos(a))
            q = p.getQuaternionFromEuler((0, a, 0))
            out.append((c, (half_w, (hi - lo) / 2, half_t), q))
    return out


def tool_boxes(task: str) -> list[tuple]:
    """The tool of ``task`` as boxes in the gripper frame: ``[(centre, half, quat_xyzw)]``."""
    ident = (0.0, 0.0, 0.0, 1.0)
    if task == "powder":
        z0, z1 = L.SPOON_SCOOP_Z
        hx, ft, wh, wt = L.SPOON_SCOOP_HALF_X, L.SPOON_FLOOR_THICKNESS, L.SPOON_WALL_HEIGHT, L.SPOON_WALL_THICKNESS
        zc, hz = (z0 + z1) / 2, (z1 - z0) / 2
        ylo, yhi = -ft, wh
        slant, flare, rim_x = L.SPOON_WALL_SLANT, L.SPOON_WALL_FLARE, L.SPOON_RIM_HALF_X
        boxes = [(L.SPOON_HANDLE[0], L.SPOON_HANDLE[1], ident),
                 ((0, -ft / 2, zc), (hx, ft / 2, hz), ident)]                             # floor
        for side in (1, -1):  # side walls hinged at the floor's edges, leaning out by the flare
            up_out = np.array([side * math.sin(flare), math.cos(flare)])   # along the wall, (x, y)
            outward = np.array([side * math.cos(flare), -math.sin(flare)])  # wall normal, outwards
            c = np.array([side * hx, 0.0]) + up_out * slant / 2 + outward * wt / 2
            q = p.getQuaternionFromEuler((0, 0, -side * flare))
            boxes.append(((c[0], c[1], zc), (wt / 2, slant / 2 + wt / 2, hz), q))
        for z_end in (z0 + wt / 2, z1 - wt / 2):  # back and front walls, as wide as the rim
            boxes.append(((0, (ylo + yhi) / 2, z_end), (rim_x, (yhi - ylo) / 2, wt / 2), ident))
        return boxes
    if task == "pour":
        r, w, zc = L.PITCHER_RADIUS, L.PITCHER_WALL, L.PITCHER_AXIS_Z
        y0, y1, yn = L.PITCHER_FLOOR_Y, L.PITCHER_RIM_Y, L.PITCHER_NOTCH_Y
        boxes = [(L.PITCHER_HANDLE[0], L.PITCHER_HANDLE[1], ident),
                 ((0, y0 - w / 2, zc), (r + w, w / 2, r + w), ident)]                     # floor
        spout = L.PITCHER_SPOUT_SEGMENT
        for c, h, q in _ring(r + w / 2, w, (y0 - w, y1), L.PITCHER_SEGMENTS, axis="y", skip=(spout,)):
            boxes.append(((c[0], c[1], c[2] + zc), h, q))
        others = [k for k in range(L.PITCHER_SEGMENTS) if k != spout]
        for c, h, q in _ring(r + w / 2, w, (y0 - w, yn), L.PITCHER_SEGMENTS, axis="y", skip=others):
            boxes.append(((c[0], c[1], c[2] + zc), h, q))                                 # notched side
        lip = np.array(L.PITCHER_SPOUT_LIP)
        start = np.array([-r, yn - w, zc])
        d = lip - start
        length = float(np.linalg.norm(d[:2]))
        q = p.getQuaternionFromEuler((0, 0, math.atan2(d[1], d[0])))                    # about z
        mid = (start + lip) / 2
        boxes.append((tuple(mid + [0, -w / 2, 0]), (length / 2 + 0.005, w / 2, 0.022), q))  # trough
        for sz in (-1, 1):
            boxes.append((tuple(mid + [0, 0.008, sz * 0.022]), (length / 2 + 0.005, 0.012, w / 2), q))
        return boxes
    raise ValueError(f"task must be 'powder' or 'pour', got {task!r}")


def tool_link_urdf(task: str, parent: str = "left_gripper") -> str:
    """URDF text of the tool link and its fixed joint to ``parent`` (spliced into Baxter's URDF)."""
    rgba = COLORS["spoon_tool"] if task == "powder" else COLORS["pitcher"]
    parts = []
    for c, h, q in tool_boxes(task):
        rpy = p.getEulerFromQuaternion(q)
        size = " ".join(f"{2 * v:.6f}" for v in h)
        origin = f'<origin xyz="{c[0]:.6f} {c[1]:.6f} {c[2]:.6f}" rpy="{rpy[0]:.6f} {rpy[1]:.6f} {rpy[2]:.6f}"/>'
        geom = f"<geometry><box size=\"{size}\"/></geometry>"
        parts.append(f"<visual>{origin}{geom}<material name=\"tool_{task}\"><color rgba=\"{' '.join(map(str, rgba))}\"/>"
                     f"</material></visual>")
        parts.append(f"<collision>{origin}{geom}</collision>")
    inertial = (f'<inertial><origin xyz="0 0 0.1"/><mass value="{L.TOOL_MASS}"/>'
                '<inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/></inertial>')
    body = "\n".join(parts)
    return (f'<link name="tool">\n{body}\n{inertial}</link>\n'
            f'<joint name="tool_fixed" type="fixed"><origin xyz="0 0 0" rpy="0 0 0"/>'
            f'<parent link="{parent}"/><child link="tool"/></joint>\n')


# PyBullet's createCollisionShapeArray / createVisualShapeArray keep at most this many shapes
# and drop the rest without a word (the bowl's floor disc, its 17th shape, was never built, so
# particles rested on the table and fell through where the bowl overhangs the table's edge)
MAX_SHAPES_PER_ARRAY = 16


def _shape_arrays(client, shapes, collide):
    """``(collision, visual)`` shape indices of ``shapes`` ``[(type, half, radius, length, pos, orn)]``
    (at most ``MAX_SHAPES_PER_ARRAY``); collision -1 when ``collide`` is False."""
    if len(shapes) > MAX_SHAPES_PER_ARRAY:
        raise ValueError(f"at most {MAX_SHAPES_PER_ARRAY} shapes per array, got {len(shapes)}")
    types, halves, radii, lengths, pos, orn = (list(col) for col in zip(*shapes))
    kw = dict(shapeTypes=types, halfExtents=halves, radii=radii, lengths=lengths)
    col = (p.createCollisionShapeArray(collisionFramePositions=pos, collisionFrameOrientations=orn,
                                       physicsClientId=client, **kw) if collide else -1)
    vis = p.createVisualShapeArray(visualFramePositions=pos, visualFrameOrientations=orn,
                                   physicsClientId=client, **kw)
    return col, vis


def _compound(client, boxes, rgba, cylinders=(), collide=True):
    """A static body from boxes ``[(centre, half, quat)]`` and cylinders ``[(centre, radius, length)]``.

    The first ``MAX_SHAPES_PER_ARRAY`` shapes form the base; any further ones form fixed links
    of the same body, so that no shape is lost. ``sim.collision`` checks the arm against the
    base only: the bowl's walls, not its floor (a link, 6 mm over the table, which the check keeps
    the arm a margin away from: about 9 mm from the floor's top, not the full margin)."""
    shapes = [(p.GEOM_BOX, h, 0, 0, c, q) for c, h, q in boxes]
    shapes += [(p.GEOM_CYLINDER, (0, 0, 0), r, ln, c, (0, 0, 0, 1)) for c, r, ln in cylinders]
    if not shapes:
        raise ValueError("a body needs at least one box or cylinder")
    n = MAX_SHAPES_PER_ARRAY
    parts = [_shape_arrays(client, shapes[k:k + n], collide) for k in range(0, len(shapes), n)]
    (col, vis), links = parts[0], parts[1:]
    k = len(links)
    body = p.createMultiBody(0, col, vis, linkMasses=[0] * k,
                             linkCollisionShapeIndices=[c for c, _ in links],
                             linkVisualShapeIndices=[v for _, v in links],
                             linkPositions=[(0, 0, 0)] * k, linkOrientations=[(0, 0, 0, 1)] * k,
                             linkInertialFramePositions=[(0, 0, 0)] * k,
                             linkInertialFrameOrientations=[(0, 0, 0, 1)] * k,
                             linkParentIndices=[0] * k, linkJointTypes=[p.JOINT_FIXED] * k,
                             linkJointAxis=[(0, 0, 1)] * k, physicsClientId=client)
    for link in range(-1, k):
        p.changeVisualShape(body, link, rgbaColor=rgba, physicsClientId=client)
    return body


def build_floor(client: int) -> int:
    """The floor: a static plane at ``FLOOR_Z`` (catches spilled particles)."""
    col = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=client)
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=(3, 3, 0.001), visualFramePosition=(0, 0, -0.001),
                              rgbaColor=(0.85, 0.85, 0.82, 1.0), physicsClientId=client)
    return p.createMultiBody(0, col, vis, basePosition=(0, 0, L.FLOOR_Z), physicsClientId=client)


def build_table(client: int) -> int:
    """The table: a top slab whose surface is at ``TABLE_TOP_Z`` plus four legs to the floor."""
    cx, cy = L.TABLE_CENTER_XY
    hx, hy = L.TABLE_HALF_XY
    t = L.TABLE_THICKNESS
    ident = (0, 0, 0, 1)
    leg_h = (L.TABLE_TOP_Z - t - L.FLOOR_Z) / 2
    boxes = [((cx, cy, L.TABLE_TOP_Z - t / 2), (hx, hy, t / 2), ident)]
    for sx in (-1, 1):
        for sy in (-1, 1):
            boxes.append(((cx + sx * (hx - L.TABLE_LEG_INSET), cy + sy * (hy - L.TABLE_LEG_INSET),
                           L.FLOOR_Z + leg_h), (0.025, 0.025, leg_h), ident))
    return _compound(client, boxes, COLORS["table"])


def build_bowl(client: int) -> int:
    """An open bowl: a floor disc and a ring of wall boxes (base frame: centre of its bottom)."""
    r, h, w = L.BOWL_RADIUS, L.BOWL_HEIGHT, L.BOWL_WALL
    boxes = _ring(r + w / 2, w, (0.0, h), L.BOWL_SEGMENTS)
    return _compound(client, boxes, COLORS["bowl"], cylinders=[((0, 0, w / 2), r + w, w)])


def build_source(client: int) -> int:
    """The source container: an open box."""
    hx, hy = L.SOURCE_HALF_XY
    h, w = L.SOURCE_HEIGHT, L.SOURCE_WALL
    ident = (0, 0, 0, 1)
    boxes = [((0, 0, w / 2), (hx + w, hy + w, w / 2), ident),
             ((hx + w / 2, 0, h / 2), (w / 2, hy + w, h / 2), ident),
             ((-hx - w / 2, 0, h / 2), (w / 2, hy + w, h / 2), ident),
             ((0, hy + w / 2, h / 2), (hx, w / 2, h / 2), ident),
             ((0, -hy - w / 2, h / 2), (hx, w / 2, h / 2), ident)]
    return _compound(client, boxes, COLORS["source"])


def build_paper_towels(client: int) -> int:
    """A paper-towel roll standing on the table (a solid cylinder)."""
    h = L.PAPER_TOWELS_HEIGHT
    return _compound(client, [], COLORS["white"], cylinders=[((0, 0, h / 2), L.PAPER_TOWELS_RADIUS, h)])


def build_lamp_shade(client: int) -> int:
    """A hanging lamp: an open shade (ring of boxes, base frame at its lower rim) and its cord."""
    h, r = L.LAMP_HEIGHT, L.LAMP_RADIUS
    boxes = _ring(r, 0.01, (0.0, h), 12)
    cord = L.LAMP_CORD_TOP_Z - (L.TABLE_TOP_Z + L.LAMP_BOTTOM_ABOVE_TABLE + h)
    ident = (0, 0, 0, 1)
    boxes.append(((0, 0, h), (r * 0.5, r * 0.5, 0.01), ident))                     # top cap
    return _compound(client, boxes, COLORS["white"], cylinders=[((0, 0, h + cord / 2), 0.006, cord)])


def build_vase(client: int) -> int:
    """A vase: a body cylinder and a narrower neck."""
    h, r = L.VASE_HEIGHT, L.VASE_RADIUS
    return _compound(client, [], COLORS["vase"],
                     cylinders=[((0, 0, 0.35 * h), r, 0.7 * h), ((0, 0, 0.85 * h), L.VASE_NECK_RADIUS, 0.3 * h)])


def build_books(client: int) -> int:
    """A stack of books, each a box, slightly rotated against each other."""
    boxes, z = [], 0.0
    for k, (sx, sy, sz) in enumerate(L.BOOK_SIZES):
        q = p.getQuaternionFromEuler((0, 0, 0.15 * (k - 1)))
        boxes.append(((0.01 * k, 0, z + sz / 2), (sx / 2, sy / 2, sz / 2), q))
        z += sz
    return _compound(client, boxes, COLORS["books"][0])


def build_small_item(client: int) -> int:
    """A flat item lying on the table (scissors, a table spoon): a thin box."""
    sx, sy, sz = L.SMALL_ITEM_SIZE
    return _compound(client, [((0, 0, sz / 2), (sx / 2, sy / 2, sz / 2), (0, 0, 0, 1))], COLORS["item"])


def build_marker(client: int) -> int:
    """A visual-only landmark marker (no collision shape)."""
    vis = p.createVisualShape(p.GEOM_SPHERE, radius=L.MARKER_RADIUS, rgbaColor=COLORS["marker"],
                              physicsClientId=client)
    return p.createMultiBody(0, -1, vis, physicsClientId=client)


# name -> (builder, kind). Kinds: "container", "obstacle", "item" (collide), "marker" (visual only).
BUILDERS = {
    "bowl": (build_bowl, "container"),
    "source": (build_source, "container"),
    "paper_towels": (build_paper_towels, "obstacle"),
    "lamp_shade": (build_lamp_shade, "obstacle"),
    "vase": (build_vase, "obstacle"),
    "books": (build_books, "obstacle"),
    "scissors": (build_small_item, "item"),
    "spoon": (build_small_item, "item"),
    **{f"marker_{k}": (build_marker, "marker") for k in range(1, 5)},
}
