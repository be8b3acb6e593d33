#!/usr/bin/env python3
"""Generates laserd's filled samples: fill-text.svg, fill-logo.svg, fill-halftone.svg,
fishhead.svg.

Run `python3 samples/generate_fills.py`; it rewrites the four files next to this
script byte for byte. It needs fontTools and the DejaVu Sans Bold font (the text is
glyph outlines, as a design program's "object to path" writes it: one path per
glyph, quadratic curves, counters as subpaths wound the other way, SVG's default
nonzero fill rule). The shapes are filled in green (#008000), the colour of the
`fill` layer of the shipped configs; none has a stroke.

Like the other samples they are 300 x 300 mm sheets with one user unit per mm
(laserd flips y: machine Y = 300 - SVG y).
"""

import math
import os

from fontTools.pens.svgPathPen import SVGPathPen
from fontTools.pens.transformPen import TransformPen
from fontTools.ttLib import TTFont

HERE = os.path.dirname(os.path.abspath(__file__))
FONT_PATHS = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans-Bold.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans-Bold.ttf",
    "/usr/share/fonts/TTF/DejaVuSans-Bold.ttf",
]
GREEN = "#008000"


def num(v):
    s = f"{v:.3f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def font():
    for path in FONT_PATHS:
        if os.path.exists(path):
            return TTFont(path)
    raise SystemExit("DejaVu Sans Bold not found (tried: " + ", ".join(FONT_PATHS) + ")")


def glyph_paths(f, text, x, baseline, height):
    """One SVG path per glyph of `text`, its cap height `height` mm, starting at x."""
    glyphs = f.getGlyphSet()
    cmap = f.getBestCmap()
    units = f["head"].unitsPerEm
    cap = getattr(f["OS/2"], "sCapHeight", 0) or 0.73 * units
    scale = height / cap
    out = []
    for ch in text:
        name = cmap[ord(ch)]
        if ch != " ":
            pen = SVGPathPen(glyphs, ntos=num)
            # Font units (y up) to sheet mm (y down).
            glyphs[name].draw(TransformPen(pen, (scale, 0, 0, -scale, x, baseline)))
            out.append((ch, pen.getCommands()))
        x += glyphs[name].width * scale
    return out, x


def circle_d(cx, cy, r, ccw=False):
    """A circle as two arcs, clockwise on the sheet (counter-clockwise with ccw)."""
    sweep = "0" if ccw else "1"
    return (f"M{num(cx + r)} {num(cy)}A{num(r)} {num(r)} 0 1 {sweep} {num(cx - r)} {num(cy)}"
            f"A{num(r)} {num(r)} 0 1 {sweep} {num(cx + r)} {num(cy)}Z")


def write(filename, title, body):
    text = (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<svg xmlns="http://www.w3.org/2000/svg" width="300mm" height="300mm" viewBox="0 0 300 300">\n'
        f"  <title>{title}</title>\n" + "".join("  " + line + "\n" for line in body) + "</svg>\n"
    )
    with open(os.path.join(HERE, filename), "w", encoding="utf-8", newline="\n") as out:
        out.write(text)


def fill_text(f):
    body = ['<g id="text">']
    for line, (size, baseline) in [("Laser fill", (12.0, 130.0)), ("made with laserd 2026", (6.0, 145.0))]:
        paths, _ = glyph_paths(f, line, 95.0, baseline, size)
        body += [f'  <path id="{line[:4].strip()}-{k}-{ch}" fill="{GREEN}" d="{d}"/>' for k, (ch, d) in enumerate(paths)]
    body.append("</g>")
    write("fill-text.svg", "laserd sample: text to fill (DejaVu Sans Bold outlines)", body)


def fill_logo(f):
    cx, cy = 150.0, 150.0
    body = ['<g id="logo">']
    # A ring: one path, the hole as a second subpath wound the same way (even-odd).
    body.append(f'  <path id="ring" fill="{GREEN}" fill-rule="evenodd" d="{circle_d(cx, cy, 28.0)}{circle_d(cx, cy, 23.0)}"/>')
    # An island in the ring's hole: a pentagram drawn as one self-crossing line
    # (nonzero fills its middle), with a round hole (wound the other way) and a
    # dot in that hole (an island in the island's hole).
    star = []
    for k in range(5):
        a = -math.pi / 2 + k * 4 * math.pi / 5
        star.append(f"{'M' if k == 0 else 'L'}{num(cx + 20.0 * math.cos(a))} {num(cy + 20.0 * math.sin(a))}")
    body.append(f'  <path id="star" fill="{GREEN}" d="{"".join(star)}Z{circle_d(cx, cy, 4.0, ccw=True)}"/>')
    body.append(f'  <circle id="dot" cx="{num(cx)}" cy="{num(cy)}" r="1.5" fill="{GREEN}"/>')
    # A badge under the ring with the letters cut out of it (even-odd).
    letters, end = glyph_paths(f, "LASERD", 0.0, 0.0, 7.0)
    width = end
    x0 = cx - width / 2
    letters, _ = glyph_paths(f, "LASERD", x0, cy + 43.5, 7.0)
    badge = f"M{num(x0 - 4)} {num(cy + 33)}H{num(x0 + width + 4)}V{num(cy + 47)}H{num(x0 - 4)}Z"
    body.append(f'  <path id="badge" fill="{GREEN}" fill-rule="evenodd" d="{badge}{"".join(d for _, d in letters)}"/>')
    # Two small marks either side: islands apart from the rest.
    for k, x in enumerate((cx - 40.0, cx + 40.0)):
        body.append(f'  <rect id="mark{k + 1}" x="{num(x - 3)}" y="{num(cy - 3)}" width="6" height="6" rx="1" fill="{GREEN}"/>')
    body.append("</g>")
    write("fill-logo.svg", "laserd sample: a logo with holes and islands to fill", body)


def fill_halftone():
    """A grey-level picture as a halftone: dots on a 1.6 mm grid, each as large as
    the picture is dark there (a lit sphere on a darker ground with a soft shadow)."""
    pitch, n = 1.6, 50
    x0, y0 = 150.0 - pitch * (n - 1) / 2, 150.0 - pitch * (n - 1) / 2
    body = ['<g id="halftone">']
    for j in range(n):
        for i in range(n):
            u, v = (i - (n - 1) / 2) / (n / 2), (j - (n - 1) / 2) / (n / 2)
            r2 = u * u + v * v
            if r2 < 0.55:
                # The sphere: lit from the top left.
                z = math.sqrt(max(0.0, 0.55 - r2) / 0.55)
                light = max(0.0, (-0.5 * u - 0.5 * v + 0.7 * z) / math.sqrt(0.99))
                dark = 1.0 - 0.9 * light
            else:
                # The ground: darker towards the bottom right, a shadow beside the sphere.
                shadow = math.exp(-((u - 0.35) ** 2 + (v - 0.45) ** 2) / 0.08)
                dark = 0.25 + 0.25 * (u + v + 2) / 4 + 0.4 * shadow
            r = 0.5 * pitch * math.sqrt(min(dark, 1.0)) * 0.95
            if r >= 0.12:
                body.append(f'  <circle cx="{num(x0 + i * pitch)}" cy="{num(y0 + j * pitch)}" r="{num(r)}" fill="{GREEN}"/>')
    body.append("</g>")
    write("fill-halftone.svg", "laserd sample: a grey-level picture as halftone dots to fill", body)


def fishhead():
    """A pocket like seed 004's "fishhead" test part: a rounded head with an
    island (a boss left standing), joined by a narrow neck (8 mm) to a tail
    pocket, and by a narrow slot (6 mm) to a small pocket above. Drawn as
    overlapping pieces wound the same way and the island wound the other way,
    so that SVG's nonzero rule makes them one area with one hole."""
    cx, cy = 95.0, 150.0

    def rect(x0, y0, x1, y1):
        # Wound the way the head's ellipse is.
        return f"M{num(x0)} {num(y0)}H{num(x1)}V{num(y1)}H{num(x0)}Z"

    head = "M" + "L".join(f"{num(cx + 40.0 * math.cos(2 * math.pi * k / 72))} {num(cy + 28.0 * math.sin(2 * math.pi * k / 72))}" for k in range(72)) + "Z"
    pieces = [
        head,
        rect(cx + 35.0, cy - 4.0, cx + 72.0, cy + 4.0),  # the neck
        rect(cx + 70.0, cy - 18.0, cx + 100.0, cy + 18.0),  # the tail pocket
        rect(cx - 12.0, cy - 47.0, cx - 6.0, cy - 24.0),  # the slot
        rect(cx - 26.0, cy - 60.0, cx + 8.0, cy - 45.0),  # the small pocket
        circle_d(cx - 5.0, cy + 4.0, 9.0, ccw=True),  # the island, wound the other way
    ]
    body = ['<g id="fishhead">', f'  <path id="pocket" fill="{GREEN}" d="{"".join(pieces)}"/>', "</g>"]
    write("fishhead.svg", "laserd sample: a pocket with an island and narrow passages (seed 004's fishhead)", body)


if __name__ == "__main__":
    f = font()
    fill_text(f)
    fill_logo(f)
    fill_halftone()
    fishhead()
