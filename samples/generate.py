#!/usr/bin/env python3
"""Generates the sample jobs of laserd: marking-300.svg, nested-sheet.svg, one-field.svg,
cut-parts.dxf and other-tool.nc.

Run `python3 samples/generate.py` from anywhere; it rewrites the three files next to
this script, byte for byte the same on every run (fixed seeds, fixed number format).
Standard library only.

All files are 300 x 300 mm sheets with one SVG user unit per mm, so SVG coordinates
are millimetres (laserd flips y: machine Y = 300 - SVG y). Every single geometry is
checked to fit a 60 x 60 mm square (the scanner's usable field is 64 x 64 mm) and to
keep at least 5 mm from the sheet edges; the script fails instead of writing a file
that breaks these promises.
"""

import math
import os
import random

HERE = os.path.dirname(os.path.abspath(__file__))
SHEET = 300.0
EDGE_MARGIN = 5.0
MAX_GEOMETRY = 60.0

# A block font of our own: each glyph on a 4 x 6 grid (x right, y down from the top
# left corner), as closed polygons: the outline first, then its counters (holes).
# Letters of "LASERD" and the digits; '5' shares the shape of 'S'.
_S = [[(0, 0), (4, 0), (4, 1), (1, 1), (1, 2.5), (4, 2.5), (4, 6), (0, 6), (0, 5), (3, 5), (3, 3.5), (0, 3.5)]]
_UPPER_COUNTER = [(1, 1), (3, 1), (3, 2.5), (1, 2.5)]
_LOWER_COUNTER = [(1, 3.5), (3, 3.5), (3, 5), (1, 5)]
FONT = {
    "L": [[(0, 0), (1, 0), (1, 5), (4, 5), (4, 6), (0, 6)]],
    "A": [[(0, 6), (0, 0), (4, 0), (4, 6), (3, 6), (3, 3.5), (1, 3.5), (1, 6)], _UPPER_COUNTER],
    "S": _S,
    "E": [[(0, 0), (4, 0), (4, 1), (1, 1), (1, 2.5), (3, 2.5), (3, 3.5), (1, 3.5), (1, 5), (4, 5), (4, 6), (0, 6)]],
    "R": [
        [(0, 0), (4, 0), (4, 3.5), (2.8, 3.5), (4, 6), (2.9, 6), (1.7, 3.5), (1, 3.5), (1, 6), (0, 6)],
        _UPPER_COUNTER,
    ],
    "D": [
        [(0, 0), (3, 0), (4, 1), (4, 5), (3, 6), (0, 6)],
        [(1, 1), (2.6, 1), (3, 1.6), (3, 4.4), (2.6, 5), (1, 5)],
    ],
    "0": [[(0, 0), (4, 0), (4, 6), (0, 6)], [(1, 1), (3, 1), (3, 5), (1, 5)]],
    "1": [[(1.5, 0), (2.5, 0), (2.5, 5), (3.5, 5), (3.5, 6), (0.5, 6), (0.5, 5), (1.5, 5), (1.5, 1.5), (0.5, 1.5), (0.5, 1)]],
    "2": [[(0, 0), (4, 0), (4, 3.5), (1, 3.5), (1, 5), (4, 5), (4, 6), (0, 6), (0, 2.5), (3, 2.5), (3, 1), (0, 1)]],
    "3": [[(0, 0), (4, 0), (4, 6), (0, 6), (0, 5), (3, 5), (3, 3.5), (1, 3.5), (1, 2.5), (3, 2.5), (3, 1), (0, 1)]],
    "4": [[(0, 0), (1, 0), (1, 2.5), (3, 2.5), (3, 0), (4, 0), (4, 6), (3, 6), (3, 3.5), (0, 3.5)]],
    "5": _S,
    "6": [[(0, 0), (4, 0), (4, 1), (1, 1), (1, 2.5), (4, 2.5), (4, 6), (0, 6)], _LOWER_COUNTER],
    "7": [[(0, 0), (4, 0), (4, 1.2), (2, 6), (0.9, 6), (2.8, 1), (0, 1)]],
    "8": [[(0, 0), (4, 0), (4, 6), (0, 6)], _UPPER_COUNTER, _LOWER_COUNTER],
    "9": [[(0, 0), (4, 0), (4, 6), (0, 6), (0, 5), (3, 5), (3, 3.5), (0, 3.5)], _UPPER_COUNTER],
}
GLYPH_ADVANCE = 5.0  # grid units per character, spaces included
GLYPH_HEIGHT = 6.0


def num(v):
    """Fixed, short number format so every run writes the same bytes."""
    s = f"{v:.3f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def poly_length(points, closed):
    n = len(points)
    segs = n if closed else n - 1
    return sum(math.dist(points[i], points[(i + 1) % n]) for i in range(segs))


class Sheet:
    """Collects the geometries of one sample file and checks each one as it is added."""

    def __init__(self, name, stroke, group_id=None):
        self.name = name
        self.stroke = stroke
        self.group_id = group_id
        self.elements = []  # SVG element text, one geometry each
        self.lo = [math.inf, math.inf]
        self.hi = [-math.inf, -math.inf]
        self.length = 0.0

    def _add(self, element, x0, y0, x1, y1, length):
        what = f"{self.name}: element {len(self.elements) + 1} ({element[:40]}...)"
        assert x1 - x0 <= MAX_GEOMETRY and y1 - y0 <= MAX_GEOMETRY, f"{what} is larger than 60 mm"
        lo, hi = EDGE_MARGIN, SHEET - EDGE_MARGIN
        assert lo <= x0 and x1 <= hi and lo <= y0 and y1 <= hi, f"{what} is within 5 mm of the edge"
        self.lo = [min(self.lo[0], x0), min(self.lo[1], y0)]
        self.hi = [max(self.hi[0], x1), max(self.hi[1], y1)]
        self.length += length
        self.elements.append(element)

    def polyline(self, points, closed):
        xs = [p[0] for p in points]
        ys = [p[1] for p in points]
        coords = " ".join(f"{num(x)},{num(y)}" for x, y in points)
        tag = "polygon" if closed else "polyline"
        self._add(f'<{tag} points="{coords}"/>', min(xs), min(ys), max(xs), max(ys), poly_length(points, closed))

    def circle(self, cx, cy, r):
        self._add(
            f'<circle cx="{num(cx)}" cy="{num(cy)}" r="{num(r)}"/>',
            cx - r, cy - r, cx + r, cy + r, 2 * math.pi * r,
        )

    def rect(self, x, y, w, h, rx=0.0):
        corner = f' rx="{num(rx)}"' if rx > 0 else ""
        length = 2 * (w + h) - 8 * rx + 2 * math.pi * rx
        self._add(
            f'<rect x="{num(x)}" y="{num(y)}" width="{num(w)}" height="{num(h)}"{corner}/>',
            x, y, x + w, y + h, length,
        )

    def slot(self, cx, cy, length, width, vertical=False):
        """A stadium (oblong hole): two half circles joined by straight sides."""
        r = width / 2
        a = (length - width) / 2  # half the distance between the arc centres
        if vertical:
            d = (f"M {num(cx + r)} {num(cy - a)} L {num(cx + r)} {num(cy + a)} "
                 f"A {num(r)} {num(r)} 0 0 1 {num(cx - r)} {num(cy + a)} L {num(cx - r)} {num(cy - a)} "
                 f"A {num(r)} {num(r)} 0 0 1 {num(cx + r)} {num(cy - a)} Z")
            box = (cx - r, cy - a - r, cx + r, cy + a + r)
        else:
            d = (f"M {num(cx - a)} {num(cy - r)} L {num(cx + a)} {num(cy - r)} "
                 f"A {num(r)} {num(r)} 0 0 1 {num(cx + a)} {num(cy + r)} L {num(cx - a)} {num(cy + r)} "
                 f"A {num(r)} {num(r)} 0 0 1 {num(cx - a)} {num(cy - r)} Z")
            box = (cx - a - r, cy - r, cx + a + r, cy + r)
        self._add(f'<path d="{d}"/>', *box, 4 * a + 2 * math.pi * r)

    def text(self, x, y, height, string):
        """Block-font text with its top-left corner at (x, y); returns the width."""
        unit = height / GLYPH_HEIGHT
        for i, ch in enumerate(string):
            for poly in FONT.get(ch, []):  # unknown characters (space) leave a gap
                ox = x + i * GLYPH_ADVANCE * unit
                self.polyline([(ox + gx * unit, y + gy * unit) for gx, gy in poly], closed=True)
        return (len(string) * GLYPH_ADVANCE - 1) * unit

    def write(self, filename, description):
        head = [
            f"<!-- {description}",
            "     Generated by samples/generate.py; edit that script, not this file. -->",
            '<svg xmlns="http://www.w3.org/2000/svg" width="300mm" height="300mm" viewBox="0 0 300 300">',
        ]
        group = f' id="{self.group_id}"' if self.group_id else ""
        head.append(f'<g{group} fill="none" stroke="{self.stroke}" stroke-width="0.1">')
        lines = head + [f"  {e}" for e in self.elements] + ["</g>", "</svg>", ""]
        with open(os.path.join(HERE, filename), "w", encoding="utf-8", newline="\n") as f:
            f.write("\n".join(lines))
        print(
            f"{filename}: {len(self.elements)} elements, extent x {num(self.lo[0])}..{num(self.hi[0])}"
            f" y {num(self.lo[1])}..{num(self.hi[1])} mm (SVG coordinates), mark length {self.length:.0f} mm"
        )


def marking_300():
    rng = random.Random(300)
    s = Sheet("marking-300.svg", "#000000")
    chars = "LASERD0123456789"

    # Lines of text of falling size across the top half.
    s.text(12, 12, 24, "LASERD")
    s.text(146, 12, 24, "300")
    s.text(12, 44, 16, "0123456789")
    y = 68.0
    for height, count in ((12, 27), (8, 40), (6, 55), (6, 55)):
        line = "".join(rng.choice(chars) if (i + 1) % 6 else " " for i in range(count))
        s.text(12, y, height, line)
        y += height + (4 if height > 6 else 3)
    # Beside the text: concentric circles and nested squares.
    for r in (6, 12, 18, 24):
        s.circle(243, 38, r)
    for side in (8, 14, 20):
        s.rect(172 - side / 2, 52 - side / 2, side, side)

    # The lower half: a grid of 26 mm cells with assorted shapes.
    kinds = ["circles", "squares", "star", "rounded", "digits", "zigzag", "spiral", "wave"]
    weights = [5, 5, 4, 3, 4, 1, 1, 1]
    for row in range(6):
        for col in range(10):
            x0, y0 = 12 + col * 28, 122 + row * 28
            cx, cy = x0 + 13, y0 + 13
            kind = rng.choices(kinds, weights)[0]
            if kind == "circles":
                for r in (12, 8, 4)[: rng.randint(1, 3)]:
                    s.circle(cx, cy, r)
            elif kind == "squares":
                s.rect(x0 + 1, y0 + 1, 24, 24)
                s.polyline([(cx, y0 + 3), (x0 + 23, cy), (cx, y0 + 23), (x0 + 3, cy)], closed=True)
            elif kind == "star":
                outer, inner, turn = 12.0, rng.uniform(4, 7), rng.uniform(0, math.pi)
                pts = []
                for k in range(10):
                    r = outer if k % 2 == 0 else inner
                    a = turn + k * math.pi / 5
                    pts.append((cx + r * math.cos(a), cy + r * math.sin(a)))
                s.polyline(pts, closed=True)
            elif kind == "rounded":
                s.rect(x0 + 1, y0 + 4, 24, 18, rx=rng.uniform(2, 6))
            elif kind == "digits":
                # 14 mm high: two digits are 21 mm wide, inside the 26 mm cell.
                s.text(x0 + 2.5, y0 + 6, 14, rng.choice("0123456789") + rng.choice("0123456789"))
            elif kind == "zigzag":
                s.polyline([(x0 + 1 + 3 * k, y0 + (4 if k % 2 else 22)) for k in range(9)], closed=False)
            elif kind == "spiral":
                pts = []
                for k in range(0, 3 * 36 + 1):
                    a = k * math.pi / 18
                    r = 12 * k / (3 * 36)
                    pts.append((cx + r * math.cos(a), cy + r * math.sin(a)))
                s.polyline(pts, closed=False)
            else:  # wave
                pts = [(x0 + 1 + k * 0.5, cy + 8 * math.sin(k * 0.5 * 2 * math.pi / 12)) for k in range(49)]
                s.polyline(pts, closed=False)

    assert 300 <= len(s.elements) <= 500, len(s.elements)
    s.write(
        "marking-300.svg",
        "laserd sample: a marking job over the whole 300 x 300 mm base (text outlines, circles,\n"
        "     rectangles, stars, a few open polylines), stroke black: the \"mark\" layer.",
    )


def nested_sheet():
    rng = random.Random(4242)
    s = Sheet("nested-sheet.svg", "#ff0000", group_id="cut")
    kinds = ["plate", "flange", "frame", "bar"]
    for row in range(4):
        for col in range(4):
            x0, y0 = 12 + col * 70, 12 + row * 70
            cx, cy = x0 + 29, y0 + 29
            kind = kinds[(row + col) % 4]
            if kind == "plate":
                # Rectangular plate: corner holes, sometimes a slot in the middle.
                w, h = rng.choice((50, 54, 58)), rng.choice((40, 46, 52))
                s.rect(cx - w / 2, cy - h / 2, w, h, rx=3)
                corners = [(-1, -1), (1, -1), (1, 1), (-1, 1)][: rng.randint(1, 4)]
                for sx, sy in corners:
                    s.circle(cx + sx * (w / 2 - 6), cy + sy * (h / 2 - 6), 2.5)
                if len(corners) < 4:
                    s.slot(cx, cy, 20, 6)
            elif kind == "flange":
                # Round flange with a big bore; a washer is nested inside the bore.
                s.circle(cx, cy, 27)
                s.circle(cx, cy, 15)
                bolts = rng.choice((2, 3, 4))
                for k in range(bolts):
                    a = math.pi / 4 + k * 2 * math.pi / bolts
                    s.circle(cx + 21 * math.cos(a), cy + 21 * math.sin(a), 2.2)
                s.circle(cx, cy, 12)
                s.circle(cx, cy, 4)
            elif kind == "frame":
                # Square frame with a big window; a small plate is nested in the window.
                s.rect(cx - 28, cy - 28, 56, 56, rx=2)
                s.rect(cx - 17, cy - 17, 34, 34, rx=4)
                s.circle(cx - 22.5, cy - 22.5, 2)
                s.circle(cx + 22.5, cy + 22.5, 2)
                s.rect(cx - 14, cy - 14, 28, 28, rx=1)
                s.circle(cx, cy, rng.choice((4, 5, 6)))
            else:
                # Slotted bar, standing or lying.
                vertical = rng.random() < 0.5
                if vertical:
                    s.rect(cx - 12, cy - 28, 24, 56, rx=4)
                else:
                    s.rect(cx - 28, cy - 12, 56, 24, rx=4)
                count = rng.randint(2, 3)
                for k in range(count):
                    off = (k - (count - 1) / 2) * 16
                    if vertical:
                        s.slot(cx, cy + off, 12, 5, vertical=False)
                    else:
                        s.slot(cx + off, cy, 12, 5, vertical=True)
    assert 40 <= len(s.elements) <= 120, len(s.elements)
    s.write(
        "nested-sheet.svg",
        "laserd sample: a 300 x 300 mm sheet of parts to cut: plates, flanges, frames and bars,\n"
        "     each an outer contour plus holes (circles, slots), small parts nested in big holes;\n"
        "     stroke red and group id \"cut\": the \"cut\" layer.",
    )


def one_field():
    s = Sheet("one-field.svg", "#0000ff", group_id="engrave")
    # Everything within 127..173 on both axes: one scan field centred on the sheet.
    width = (6 * GLYPH_ADVANCE - 1) * 1.0  # "LASERD" at 6 mm high: 1 mm per grid unit
    s.text(150 - width / 2, 128, 6, "LASERD")
    for k in range(3):
        s.circle(138 + 12 * k, 141, 3)
    for i in range(3):
        for j in range(3):
            s.rect(142.5 + 6 * i, 148 + 6 * j, 3, 3)
    s.text(150 - (2 * GLYPH_ADVANCE - 1) / 2, 166, 6, "42")
    assert 15 <= len(s.elements) <= 30, len(s.elements)
    assert s.length <= 600, s.length
    assert 125 <= min(s.lo) and max(s.hi) <= 175, (s.lo, s.hi)
    s.write(
        "one-field.svg",
        "laserd sample: a small job that fits one scan field: letters, circles and a grid of\n"
        "     squares within 50 x 50 mm centred on the 300 x 300 mm sheet; stroke blue and group\n"
        "     id \"engrave\": the \"engrave\" layer. Short on purpose: streamed in real time in tests.",
    )


class Dxf:
    """An AutoCAD R12 ASCII DXF (readable by every CAD program and DXF
    library), drawn as CAD programs export parts: outlines as separate LINE
    and ARC entities or as POLYLINEs with bulges, holes as CIRCLEs, a
    repeated part as a BLOCK inserted several times. Layer CUT, mm."""

    def __init__(self):
        self.blocks = []
        self.entities = []
        self.count = 0

    @staticmethod
    def pairs(*groups):
        return [f"{code}\n{value}" for code, value in groups]

    def line(self, a, b, into=None):
        (into if into is not None else self.entities).extend(
            self.pairs((0, "LINE"), (8, "CUT"), (10, num(a[0])), (20, num(a[1])), (11, num(b[0])), (21, num(b[1])))
        )
        self.count += into is None

    def arc(self, c, r, start, end, into=None):
        (into if into is not None else self.entities).extend(
            self.pairs((0, "ARC"), (8, "CUT"), (10, num(c[0])), (20, num(c[1])), (40, num(r)), (50, num(start)), (51, num(end)))
        )
        self.count += into is None

    def circle(self, c, r, into=None):
        (into if into is not None else self.entities).extend(self.pairs((0, "CIRCLE"), (8, "CUT"), (10, num(c[0])), (20, num(c[1])), (40, num(r))))
        self.count += into is None

    def polyline(self, vertices, into=None):
        """A closed 2D POLYLINE of (x, y, bulge) vertices."""
        out = into if into is not None else self.entities
        out.extend(self.pairs((0, "POLYLINE"), (8, "CUT"), (66, 1), (10, 0), (20, 0), (70, 1)))
        for x, y, bulge in vertices:
            out.extend(self.pairs((0, "VERTEX"), (8, "CUT"), (10, num(x)), (20, num(y)), (42, num(bulge))))
        out.extend(self.pairs((0, "SEQEND"), (8, "CUT")))
        self.count += into is None

    def rect_lines(self, x0, y0, x1, y1):
        for a, b in (((x0, y0), (x1, y0)), ((x1, y0), (x1, y1)), ((x1, y1), (x0, y1)), ((x0, y1), (x0, y0))):
            self.line(a, b)

    def block(self, name, draw):
        body = []
        draw(body)
        self.blocks.extend(self.pairs((0, "BLOCK"), (8, "0"), (2, name), (70, 0), (10, 0), (20, 0)) + body + self.pairs((0, "ENDBLK"), (8, "0")))

    def insert(self, name, at, rotation=0.0):
        self.entities.extend(self.pairs((0, "INSERT"), (8, "CUT"), (2, name), (10, num(at[0])), (20, num(at[1])), (50, num(rotation))))

    def write(self, filename, comment):
        out = self.pairs((999, comment), (0, "SECTION"), (2, "HEADER"), (9, "$ACADVER"), (1, "AC1009"), (9, "$INSUNITS"), (70, 4), (0, "ENDSEC"))
        out += self.pairs((0, "SECTION"), (2, "BLOCKS")) + self.blocks + self.pairs((0, "ENDSEC"))
        out += self.pairs((0, "SECTION"), (2, "ENTITIES")) + self.entities + self.pairs((0, "ENDSEC"), (0, "EOF"))
        with open(os.path.join(HERE, filename), "w", encoding="utf-8", newline="\n") as f:
            f.write("\n".join(out) + "\n")
        print(f"{filename}: {len(self.entities)} entity lines, {self.count} model-space curves")


def cut_parts_dxf():
    """A plate of parts as a CAD program exports it: two plates sharing an
    edge, one with holes and a slot drawn as lines and arcs; a part on the
    plate's edge (x = 0); a rounded frame (bulges) with a part nested in its
    window; a flange block (bore and bolt holes) inserted three times, once
    turned. All in mm, on layer CUT."""
    d = Dxf()
    # Two plates side by side: the edge x = 90 belongs to both outlines.
    d.rect_lines(10, 10, 90, 60)
    d.rect_lines(90, 10, 150, 60)
    d.circle((20, 20), 3)
    d.circle((80, 50), 3)
    # A slot in the first plate: two lines and two arcs, end to end.
    d.line((35, 30), (65, 30))
    d.arc((65, 35), 5, 270, 90)
    d.line((65, 40), (35, 40))
    d.arc((35, 35), 5, 90, 270)
    # A part on the plate's edge.
    d.polyline([(0, 80, 0), (40, 80, 0), (40, 120, 0), (0, 120, 0)])
    # A frame with rounded corners (bulge tan(22.5°) turns 90°), its window, and
    # a part nested in the window.
    b = math.tan(math.radians(22.5))
    d.polyline([(65, 80, 0), (135, 80, b), (140, 85, 0), (140, 125, b), (135, 130, 0), (65, 130, b), (60, 125, 0), (60, 85, b)])
    d.polyline([(75, 92, 0), (125, 92, 0), (125, 118, 0), (75, 118, 0)])
    d.polyline([(85, 98, 0), (115, 98, 0), (115, 112, 0), (85, 112, 0)])

    def flange(body):
        d.circle((0, 0), 15, body)
        d.circle((0, 0), 5, body)
        for k in range(4):
            a = math.radians(45 + 90 * k)
            d.circle((10 * math.cos(a), 10 * math.sin(a)), 1.5, body)

    d.block("FLANGE", flange)
    d.insert("FLANGE", (180, 35))
    d.insert("FLANGE", (220, 35), 45)
    d.insert("FLANGE", (200, 100))
    d.write("cut-parts.dxf", "laserd sample: parts to cut, as a CAD program exports them. Generated by samples/generate.py; edit that script, not this file.")


def other_tool_nc():
    """A G-code job as a sender such as LightBurn writes it: its header, air
    assist, parts in the order they were drawn (not the shortest), squares as
    G1 moves, circles as two G2 half arcs, laser on with S in M4 mode."""
    out = ["; laserd sample: a G-code job as another tool writes it. Generated by samples/generate.py.",
           "G00 G17 G40 G21 G54", "G90", "M4", "M8"]
    rng = random.Random(7)
    parts = [(20 + 40 * (k % 6), 20 + 40 * (k // 6)) for k in range(18)]
    rng.shuffle(parts)
    for k, (x, y) in enumerate(parts):
        if k % 2 == 0:
            # A 25 mm square, cut at 20 mm/s.
            corners = [(x, y), (x + 25, y), (x + 25, y + 25), (x, y + 25), (x, y)]
            out.append(f"G0 X{num(corners[0][0])} Y{num(corners[0][1])}")
            out.append(f"G1 X{num(corners[1][0])} Y{num(corners[1][1])} S800 F1200")
            out += [f"G1 X{num(cx)} Y{num(cy)}" for cx, cy in corners[2:]]
        else:
            # A circle of 10 mm radius as two half arcs, cut at 15 mm/s.
            out.append(f"G0 X{num(x + 22.5)} Y{num(y + 12.5)}")
            out.append(f"G2 X{num(x + 2.5)} Y{num(y + 12.5)} I-10 J0 S1000 F900")
            out.append(f"G2 X{num(x + 22.5)} Y{num(y + 12.5)} I10 J0")
        out.append("G1 S0")
    out += ["M9", "M5", "G0 X0 Y0", "M2"]
    with open(os.path.join(HERE, "other-tool.nc"), "w", encoding="utf-8", newline="\n") as f:
        f.write("\n".join(out) + "\n")
    print(f"other-tool.nc: {len(out)} lines, {len(parts)} parts")


def raster_tool_nc():
    """A raster engraving as raster senders write it: a disc shaded from dark
    in the middle to light at its rim, 0.5 mm pixels, scan lines both ways at
    50 mm/s, one G1 per run of pixels of one power (S), G0 over the white
    around the disc."""
    out = ["; laserd sample: a raster engraving as another tool writes it. Generated by samples/generate.py.",
           "G00 G17 G40 G21 G54", "G90", "M4"]
    cx, cy, r, pixel = 150.0, 150.0, 10.0, 0.5
    lines = 0
    for row in range(int(2 * r / pixel) + 1):
        y = cy - r + row * pixel
        # The lit pixels of this line: inside the disc.
        lit = [k for k in range(int(2 * r / pixel)) if math.hypot(cx - r + (k + 0.5) * pixel - cx, y - cy) < r]
        if not lit:
            continue
        power = lambda k: int(round((200 + 600 * (1 - math.hypot(cx - r + (k + 0.5) * pixel - cx, y - cy) / r)) / 50)) * 50
        ks = lit if lines % 2 == 0 else lit[::-1]
        step = 1 if lines % 2 == 0 else -1
        edge = lambda k: cx - r + (k + (0 if step > 0 else 1)) * pixel
        out.append(f"G0 X{num(edge(ks[0]))} Y{num(y)}")
        feed = " F3000"
        for i, k in enumerate(ks):
            # A run ends where the next pixel's power differs.
            if i + 1 < len(ks) and power(ks[i + 1]) == power(k):
                continue
            out.append(f"G1 X{num(edge(k) + step * pixel)} S{power(k)}{feed}")
            feed = ""
        out.append("G1 S0")
        lines += 1
    out += ["M5", "G0 X0 Y0", "M2"]
    with open(os.path.join(HERE, "raster-tool.nc"), "w", encoding="utf-8", newline="\n") as f:
        f.write("\n".join(out) + "\n")
    print(f"raster-tool.nc: {len(out)} lines, {lines} scan lines")


if __name__ == "__main__":
    marking_300()
    nested_sheet()
    one_field()
    cut_parts_dxf()
    other_tool_nc()
    raster_tool_nc()
