#!/usr/bin/env python3
"""Writes the seed corpora under fuzz/corpus/<target>/seed-*: from samples/,
tests/data and config/, a recording and programs that laserd makes of
samples/, and a few hand-written inputs for what those do not hold.

Run from the repository root after `cargo build --release`:
    python3 fuzz/make_seeds.py
"""
import pathlib
import subprocess
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
CORPUS = ROOT / "fuzz" / "corpus"
LASERD = ROOT / "target" / "release" / "laserd"


def put(target, name, data):
    d = CORPUS / target
    d.mkdir(parents=True, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    (d / f"seed-{name}").write_bytes(data)


def clear():
    for d in CORPUS.glob("*"):
        for f in d.glob("seed-*"):
            f.unlink()


def svg_seeds():
    for f in sorted((ROOT / "samples").glob("*.svg")):
        put("svg_import", f.stem + ".svg", f.read_bytes())
    # The smaller galvo instances only: the large ones add size, not structure.
    for f in sorted((ROOT / "tests/data/galvo").glob("*.svg")):
        if f.stat().st_size < 12000:
            put("svg_import", f.stem + ".svg", f.read_bytes())
    svg = '<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="{vb}">{body}</svg>'
    put("svg_import", "arcs.svg", svg.format(w="50mm", h="50mm", vb="0 0 50 50", body=(
        '<path d="M 10 10 A 2.5 2.5 0 0 1 20 10 a 5 3 30 1 0 5 5 Z" fill="none" stroke="#000"/>'
        '<path d="M5 40 Q 10 30 20 40 T 40 40 S 45 30 48 45 C 1 2 3 4 5 6 z" stroke="red" fill="none"/>')))
    put("svg_import", "transforms.svg", svg.format(w="100", h="100", vb="0 0 100 100", body=(
        '<g id="cut" transform="translate(10 10) rotate(30) scale(2 0.5) skewX(10)">'
        '<rect x="1" y="1" width="10" height="5" rx="1" stroke="#ff0000" fill="none"/>'
        '<ellipse cx="20" cy="20" rx="5" ry="2" stroke="#0000ff" fill="none"/></g>'
        '<g style="display:none"><line x1="0" y1="0" x2="5" y2="5" stroke="black"/></g>'
        '<polyline points="0,0 10,10 20,0 30,10" stroke="black" fill="none"/>'
        '<polygon points="50,50 60,60 50,70" stroke="black" fill="none" opacity="0.5"/>')))
    put("svg_import", "use-defs.svg", svg.format(w="30mm", h="20mm", vb="0 0 30 20", body=(
        '<defs><path id="p" d="M0 0 h5 v5 h-5 z"/><clipPath id="c"><rect width="10" height="10"/></clipPath></defs>'
        '<use href="#p" x="3" y="3" stroke="#000"/><use href="#p" x="12" y="3" stroke="#000" clip-path="url(#c)"/>'
        '<style>.a { stroke: #ff0000; fill: none }</style><circle class="a" cx="20" cy="10" r="4"/>'
        '<text x="1" y="18">text</text>')))
    put("svg_import", "units.svg", '<svg xmlns="http://www.w3.org/2000/svg" width="2in" height="3cm">'
        '<path d="M1e3,1e-3L.5.5l-1-1e1H 3V4h5v5" stroke="#000" fill="none" stroke-width="0.1pt"/></svg>')


def config_seeds():
    for f in sorted((ROOT / "config").glob("*.toml")):
        put("config_text", f.name, f.read_bytes())
    # The shipped machine without its scanner: a stage-only one.
    kept, skipping = [], False
    for line in (ROOT / "config/laserd.toml").read_text().splitlines(keepends=True):
        if line.startswith("["):
            skipping = line.strip() == "[scanner]"
        if not skipping:
            kept.append(line)
    put("config_text", "no-scanner.toml", "".join(kept))


def controller_lines(path, n):
    return "".join(l + "\n" for l in path.read_text().splitlines()[:n])


def sim_seeds(one_field_nc, nested_nc):
    # First byte: bit 0 grblHAL, bit 1 Grbl's motion model, bit 2 four axes, bit 3 a probe.
    put("sim_controller", "one-field-timed.nc", b"\x04" + controller_lines(one_field_nc, 60).encode())
    put("sim_controller", "nested-grbl.nc", b"\x02" + controller_lines(nested_nc, 60).encode())
    put("sim_controller", "nested-grblhal.nc", b"\x03" + controller_lines(nested_nc, 30).encode())
    put("sim_controller", "system-commands", b"\x00$$\n$I\n$G\n$#\n$N\n$\n$C\nG0X10\n$C\n$X\n$10=0\n?$10=2\n?$SLP\n")
    put("sim_controller", "realtime", b"\x00G1X50Y50F600\n?!?\x85~\x91\x92\x93\x94\x95\x96\x97\x99\x9a\x9b\x9c\x9d\x9e\xa0\xa1?\x18?$X\n")
    put("sim_controller", "jog", b"\x00$J=G91X10F600\n?\x85$J=X100Y20F1000\n$J=G53Y5F100\n?")
    put("sim_controller", "offsets-arcs", b"\x00G10L2P1X10Y5\nG55\nG10L20P2X0\nG92X1\nG92.1\nG28.1\nG30.1\nG28\n"
        b"G17G2X20Y0I10J0F300\nG3X0Y0R10\nG18G2X5Z1K2\nG19G3Y1Z2J1\nG20G91G1X0.1F10\nG21G90\nG53G0X1\nG4P0.2\nM0\n~M2\n")
    put("sim_controller", "laser-modes", b"\x00$32=1\nG1F600\nM3S500\nG4P0.1\nM4S200\nX10\nS0\nM5\n$32=0\nM3S100\nM7\nM8\nM9\nG43.1Z-1\nG49\nM30\n")
    put("sim_controller", "probe-home", b"\x08G38.2X5F100\nG38.3Y-5F100\nG38.4X-1F50\nG38.5Y1F50\n$22=1\n$H\n$HX\n$RST=#\n$RST=$\n")
    put("sim_controller", "hal-realtime", b"\x01?\x87\x80\x81\x82G1X1F10\n\x84\x18N10G1X5Y5F300\n$I\n")
    put("sim_controller", "errors", b"\x00G1X\nG99\nM3M5\nG0G1X1\nX1X2\nG1F-5X1\nG2X1\nN999999999G0\n" + b"G0" * 70 + b"\n$999=1\n$10=abc\nT-1\n")


def response_seeds():
    put("controller_responses", "connect-grbl", "Grbl 1.1h ['$' for help]\r\n<Idle|MPos:0.000,0.000|Bf:15,128|FS:0,0>\r\n"
        "[VER:1.1h.laserd-sim:]\r\n[OPT:VNM+,15,128]\r\nok\r\n")
    put("controller_responses", "connect-grblhal", "GrblHAL 1.1f ['$' or '$HELP' for help]\r\n"
        "<Idle|MPos:0.000,0.000,0.000,0.000|Bf:100,1023|FS:0,0|Pn:P|WCO:0.000,0.000,0.000,0.000|Ov:100,100,100|A:SFM|FW:grblHAL>\r\n"
        "[VER:1.1f.20240101:]\r\n[OPT:VNMSL,100,1024,4,0]\r\n[AXS:4:XYZA]\r\n[FIRMWARE:grblHAL]\r\nok\r\n")
    put("controller_responses", "streaming", "ok\nok\n<Run|MPos:12.345,-6.789|Bf:3,17|Ln:42|FS:1200,500>\nok\n"
        "<Hold:0|MPos:1.000,2.000|Bf:0,0|FS:0,0|Ov:120,100,80|A:C>\n<Hold:1|WPos:1.000,2.000|F:300>\n"
        "<Jog|MPos:5.000,5.000|Bf:14,128|FS:600,0>\n<Door:2|MPos:0,0>\nerror:20\nALARM:2\n[MSG:Reset to continue]\n")
    put("controller_responses", "settings", "".join(f"${n}={v}\r\n" for n, v in [
        (0, 10), (1, 25), (10, 1), (11, "0.010"), (30, 1000), (32, 1), (100, "250.000"), (110, "500.000 (x max rate)"), (120, "10.000")]) + "ok\r\n")
    put("controller_responses", "feedback", "[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]\r\n[G54:0.000,0.000]\r\n[PRB:1.000,2.000:1]\r\n"
        "[TLO:0.000]\r\n[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]\r\n[echo:G1X1]\r\n>G1X1:ok\r\n")
    put("controller_responses", "odd", "<Idle|MPos:NaN,inf|Bf:15,128>\n<Alarm|MPos:-0.0004,1e300|Ln:4294967295>\n<Sleep>\n<Check|WCO:1,2>\n"
        "<Tool|MPos:1|Bf:1,2,3>\nerror:99999\nALARM:\nGrbl \n\x07#~garbage~#\r\n")


def mcap_seeds(recording):
    data = recording.read_bytes()
    put("mcap_replay", "one-field.mcap", data)
    # A run cut short: the reader keeps what came before.
    put("mcap_replay", "one-field-cut.mcap", data[: len(data) // 3])
    put("mcap_replay", "one-field-head.mcap", data[:4096])


def api_seeds():
    # First byte: 0 submit by path, 1 move, 2 start, 3 resume, 4 jog.
    for name, which, body in [
        ("submit", 0, '{"path": "/srv/jobs/part.svg"}'),
        ("move", 1, '{"position": 0}'),
        ("move-big", 1, '{"position": 18446744073709551615}'),
        ("start", 2, '{"id": "000042"}'),
        ("start-null", 2, '{"id": null}'),
        ("resume", 3, '{"confirm": true, "from": 6818}'),
        ("resume-default", 3, '{}'),
        ("jog", 4, '{"block": "G91 X10 F600"}'),
        ("jog-escaped", 4, '{"block": "G91\\u0000X\\ud83d\\ude00 F600", "extra": [1, {"a": 2.5e308}]}'),
    ]:
        put("api_bodies", name, bytes([which]) + body.encode())


def dxf_seeds():
    for f in sorted((ROOT / "samples").glob("*.dxf")):
        put("dxf_import", f.name, f.read_bytes())
    put("dxf_import", "self-insert.dxf", "0\nSECTION\n2\nBLOCKS\n0\nBLOCK\n8\n0\n2\nA\n70\n0\n10\n0\n20\n0\n0\nINSERT\n8\n0\n2\nA\n10\n1\n20\n1\n"
        "0\nENDBLK\n0\nENDSEC\n0\nSECTION\n2\nENTITIES\n0\nINSERT\n5\n3C\n8\n0\n2\nA\n10\n0\n20\n0\n0\nENDSEC\n0\nEOF\n")
    put("dxf_import", "spline.dxf", "0\nSECTION\n2\nENTITIES\n0\nSPLINE\n5\n4D\n8\n0\n71\n2\n72\n6\n40\n0\n40\n0\n40\n0\n40\n1\n40\n1\n40\n1\n73\n3\n"
        "10\n0\n20\n0\n30\n0\n10\n5\n20\n9\n30\n0\n10\n10\n20\n0\n30\n0\n0\nENDSEC\n0\nEOF\n")
    # Every entity kind, ASCII and binary, where ezdxf (the tests' DXF writer) is installed.
    try:
        import ezdxf
    except ImportError:
        return
    doc = ezdxf.new("R2010")
    msp = doc.modelspace()
    msp.add_lwpolyline([(0, 0, 0.5), (10, 0, 0), (10, 10, 0)], format="xyb", close=True)
    msp.add_ellipse((5, 5), major_axis=(3, 1), ratio=0.5, start_param=0.2, end_param=2.0)
    msp.add_open_spline([(0, 0), (2, 3), (4, 0), (6, 3)], degree=3)
    block = doc.blocks.new("B")
    block.add_circle((0, 0), 1)
    msp.add_blockref("B", (20, 20), dxfattribs={"xscale": -1, "rotation": 30, "column_count": 2, "row_count": 2, "column_spacing": 3, "row_spacing": 3})
    with tempfile.TemporaryDirectory() as tmp:
        for fmt in ("asc", "bin"):
            path = pathlib.Path(tmp) / f"entities-{fmt}.dxf"
            doc.saveas(path, fmt=fmt)
            put("dxf_import", path.name, path.read_bytes())


def main():
    clear()
    svg_seeds()
    dxf_seeds()
    config_seeds()
    response_seeds()
    api_seeds()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        one_field_nc, nested_nc, recording = tmp / "one-field.nc", tmp / "nested.nc", tmp / "one-field.mcap"
        run = lambda *args: subprocess.run([str(LASERD), *args], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
        run("plan", "samples/one-field.svg", "-o", str(one_field_nc))
        run("plan", "samples/nested-sheet.svg", "--config", "config/flatbed-cutter.toml", "--time-limit", "2", "-o", str(nested_nc))
        run("dry-run", "samples/one-field.svg", "--record", str(recording))
        sim_seeds(one_field_nc, nested_nc)
        mcap_seeds(recording)


if __name__ == "__main__":
    main()
