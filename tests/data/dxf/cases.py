"""Writes DXF test drawings with ezdxf (an independent writer) and ezdxf's
own reading of them, for tests/dxf_import.rs.

Usage: python3 cases.py OUT_DIR

For each drawing, ASCII and binary, in mm and in inch ($INSUNITS 4 and 1),
it writes OUT_DIR/<name>.dxf and, in OUT_DIR/expected.json, what ezdxf
reads back from that file: the number of curves laserd should make (the
model space's curves with blocks exploded; the four pieces of the slot,
which meet end to end, count as one contour), their total true length and
their bounds, both in mm.
"""
import json
import math
import sys

import ezdxf
from ezdxf import bbox
from ezdxf.math import Vec3

CURVES = {"LINE", "ARC", "CIRCLE", "LWPOLYLINE", "POLYLINE", "ELLIPSE", "SPLINE"}


def build(doc, s):
    """The drawing, in drawing units of `s` mm (every length divided by s)."""
    msp = doc.modelspace()
    u = 1.0 / s
    # A slot drawn as CAD programs export outlines: two lines and two arcs.
    msp.add_line((10 * u, 10 * u), (40 * u, 10 * u), dxfattribs={"layer": "CUT"})
    msp.add_arc((40 * u, 15 * u), 5 * u, 270, 90, dxfattribs={"layer": "CUT"})
    msp.add_line((40 * u, 20 * u), (10 * u, 20 * u), dxfattribs={"layer": "CUT"})
    msp.add_arc((10 * u, 15 * u), 5 * u, 90, 270, dxfattribs={"layer": "CUT"})
    msp.add_circle((60 * u, 15 * u), 4 * u, dxfattribs={"layer": "CUT"})
    # A rounded plate as one closed polyline with bulges, and an open one.
    msp.add_lwpolyline([(10 * u, 30 * u, 0), (50 * u, 30 * u, 0.4142135623730951), (55 * u, 35 * u, 0), (55 * u, 60 * u, 0), (10 * u, 60 * u, -0.3)], format="xyb", close=True, dxfattribs={"layer": "CUT"})
    msp.add_lwpolyline([(70 * u, 30 * u, 0.5), (80 * u, 30 * u, 0), (90 * u, 40 * u, 0)], format="xyb", dxfattribs={"layer": "MARK"})
    msp.add_polyline2d([(100 * u, 10 * u), (110 * u, 12 * u), (120 * u, 10 * u)], dxfattribs={"layer": "MARK"})
    # A full ellipse, an elliptic arc, a clamped cubic spline and a rational
    # quadratic one (as CAD programs write them: control points and knots).
    msp.add_ellipse((80 * u, 70 * u), major_axis=(12 * u, 4 * u), ratio=0.5)
    msp.add_ellipse((110 * u, 70 * u), major_axis=(0, 8 * u), ratio=0.3, start_param=0.3, end_param=2.5)
    msp.add_open_spline([(10 * u, 80 * u), (20 * u, 95 * u), (35 * u, 75 * u), (50 * u, 90 * u), (60 * u, 80 * u)], degree=3)
    msp.add_rational_spline([(70 * u, 85 * u), (80 * u, 100 * u), (95 * u, 85 * u), (100 * u, 95 * u)], [1.0, 2.5, 0.7, 1.0], degree=2)
    # Splines given by fit points only, as AutoCAD's SPLINE command writes
    # them: with natural ends, and leaving along given end tangents.
    msp.add_spline([(110 * u, 80 * u), (118 * u, 92 * u), (126 * u, 84 * u), (134 * u, 96 * u), (140 * u, 88 * u)])
    tangent = msp.add_spline([(150 * u, 80 * u), (160 * u, 95 * u), (172 * u, 82 * u)])
    tangent.dxf.start_tangent = (0, 1, 0)
    tangent.dxf.end_tangent = (1, -1, 0)
    # A block (a triangle with a hole) inserted scaled, rotated, mirrored,
    # nested, and as a 2 x 3 array.
    part = doc.blocks.new(name="PART", base_point=(1 * u, 1 * u))
    part.add_lwpolyline([(0, 0), (8 * u, 0), (0, 6 * u)], close=True)
    part.add_circle((2 * u, 2 * u), 1 * u)
    outer = doc.blocks.new(name="OUTER")
    outer.add_blockref("PART", (0, 0), dxfattribs={"rotation": 15})
    outer.add_line((0, 0), (0, -3 * u))
    msp.add_blockref("PART", (130 * u, 20 * u), dxfattribs={"xscale": 1.5, "yscale": 0.75, "rotation": 30})
    msp.add_blockref("PART", (160 * u, 20 * u), dxfattribs={"xscale": -1, "yscale": 1})
    msp.add_blockref("OUTER", (130 * u, 50 * u), dxfattribs={"xscale": 2, "yscale": 2, "rotation": -20})
    msp.add_blockref("PART", (170 * u, 60 * u), dxfattribs={"column_count": 2, "row_count": 3, "column_spacing": 12 * u, "row_spacing": 9 * u, "rotation": 10})
    # Not curves: skipped with a warning, or a point ignored.
    msp.add_text("LABEL", dxfattribs={"insert": (10 * u, 100 * u), "height": 3 * u})
    msp.add_point((5 * u, 5 * u))


def length(e):
    kind = e.dxftype()
    if kind == "LINE":
        return (e.dxf.end - e.dxf.start).magnitude
    if kind == "CIRCLE":
        return 2 * math.pi * e.dxf.radius
    if kind == "ARC":
        sweep = (e.dxf.end_angle - e.dxf.start_angle) % 360 or 360
        return math.radians(sweep) * e.dxf.radius
    if kind in ("LWPOLYLINE", "POLYLINE"):
        points = list(e.get_points("xyb")) if kind == "LWPOLYLINE" else [(v.dxf.location.x, v.dxf.location.y, v.dxf.bulge) for v in e.vertices]
        n = len(points)
        total = 0.0
        for i in range(n if e.is_closed else n - 1):
            x0, y0, b = points[i][0], points[i][1], points[i][2]
            x1, y1 = points[(i + 1) % n][0], points[(i + 1) % n][1]
            chord = math.hypot(x1 - x0, y1 - y0)
            if abs(b) < 1e-12:
                total += chord
            else:
                theta = 4 * math.atan(abs(b))
                total += chord / (2 * math.sin(theta / 2)) * theta
        return total
    # Ellipses and splines: ezdxf's own flattening, far finer than laserd's.
    pts = list(e.construction_tool().flattening(1e-7)) if kind == "SPLINE" else list(e.construction_tool().vertices(e.construction_tool().params(200000)))
    return sum((b - a).magnitude for a, b in zip(pts, pts[1:]))


def curves(entities, depth=0):
    for e in entities:
        if e.dxftype() == "INSERT":
            for m in e.multi_insert():
                yield from curves(m.virtual_entities(), depth + 1)
        elif e.dxftype() in CURVES:
            yield e


def main(out):
    expected = {}
    for units, s, insunits in (("mm", 1.0, 4), ("inch", 25.4, 1)):
        for fmt in ("asc", "bin"):
            doc = ezdxf.new("R2010")
            doc.header["$INSUNITS"] = insunits
            build(doc, s)
            name = f"drawing-{units}-{fmt}.dxf"
            doc.saveas(f"{out}/{name}", fmt=fmt)
            read = ezdxf.readfile(f"{out}/{name}")
            msp = read.modelspace()
            found = list(curves(msp))
            box = bbox.extents(found, fast=False)
            expected[name] = {
                # The slot's four pieces are one contour.
                "geometries": len(found) - 3,
                "length_mm": sum(length(e) for e in found) * s,
                "min_mm": [box.extmin.x * s, box.extmin.y * s],
                "max_mm": [box.extmax.x * s, box.extmax.y * s],
                "closed_slot": True,
            }
    with open(f"{out}/expected.json", "w") as f:
        json.dump(expected, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1])
