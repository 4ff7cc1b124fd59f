#!/usr/bin/env python3
"""Makes the fuzz seed corpora (fuzz/corpus/<target>/) from the real files in data/ and
../shared/data/: small crops and subsets of them (a few KB each), so that libFuzzer mutates
real structure quickly. Run once by hand when a reader gains a format; the output is
committed, so fuzzing needs no Python.

    python3 -m venv /tmp/seedenv && /tmp/seedenv/bin/pip install numpy pydicom pillow \
        pylibjpeg pylibjpeg-openjpeg
    /tmp/seedenv/bin/python fuzz/make_corpus.py

Sources and licences (all permit redistribution of derived files; see corpus/README.md):
  data/anatomy/arch-to-cow/vessels.obj, centerlines/*.mrk.json   MIT (stEVE_bench)
  data/anatomy/arch-to-cow-open/vessels_open.vtp                  MIT
  data/ct/aorta.mha, data/ct/aorta-vmtk-surface.vtp               BSD-3-Clause (VMTK)
  data/ct/totalsegmentator-example/dicom/                         Apache-2.0 (TotalSegmentator)
  ../shared/data/ct/totalsegmentator-example/example_ct.nii.gz    Apache-2.0
  ../shared/data/ct/rorden-ct-template/scct.nii                   BSD-2-Clause (Rorden)
  scenes/*.toml, server/physics/devices/catalogue.toml            this project (Apache-2.0)
"""

import base64
import copy
import glob
import gzip
import io
import json
import os
import shutil
import struct
import sys
import tomllib
import zlib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.join(os.path.dirname(ROOT), "shared", "data")
OUT = os.path.join(ROOT, "fuzz", "corpus")
# Separates the files of a multi-file input (a DICOM series, a .mhd header and its raw data);
# the same bytes as cathlab_fuzz::NEXT_FILE.
NEXT_FILE = b"\n\xffNEXT-FILE\xff\n"


def path(*p):
    return os.path.join(ROOT, *p)


def write(target, name, data):
    d = os.path.join(OUT, target)
    os.makedirs(d, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


# --- surfaces: a subset of the real OBJ (triangles and quads) -----------------------------

def read_obj(p):
    verts, norms, faces, header = [], [], [], []
    for line in open(p):
        t = line.split()
        if not t:
            continue
        if t[0] == "v":
            verts.append(tuple(float(x) for x in t[1:4]))
        elif t[0] == "vn":
            norms.append(tuple(float(x) for x in t[1:4]))
        elif t[0] == "f":
            faces.append([tuple(int(x) if x else 0 for x in c.split("/")) for c in t[1:]])
        elif t[0] in ("#", "mtllib", "o", "s", "usemtl"):
            header.append(line.rstrip("\n"))
    return verts, norms, faces, header


VERTS, NORMS, FACES, HEADER = read_obj(path("data/anatomy/arch-to-cow/vessels.obj"))


def subset(n, start=0):
    """n faces from `start`, their vertices re-indexed: (verts, faces as index lists)."""
    faces = FACES[start:start + n]
    used = sorted({c[0] for f in faces for c in f})
    index = {v: i for i, v in enumerate(used)}
    return [VERTS[v - 1] for v in used], [[index[c[0]] for c in f] for f in faces], faces


def triangles(faces):
    return [(f[0], f[k], f[k + 1]) for f in faces for k in range(1, len(f) - 1)]


def obj_text(n, start=0, normals=True):
    verts, faces, raw = subset(n, start)
    out = HEADER[:4] + ["v %.6f %.6f %.6f" % v for v in verts]
    if normals:
        nused = sorted({c[2] for f in raw for c in f if len(c) > 2 and c[2]})
        nindex = {v: i + 1 for i, v in enumerate(nused)}
        out += ["vn %.4f %.4f %.4f" % NORMS[v - 1] for v in nused]
        out += ["f " + " ".join("%d//%d" % (i + 1, nindex[c[2]]) for i, c in zip(f, r))
                for f, r in zip(faces, raw)]
    else:
        out += ["f " + " ".join(str(i + 1) for i in f) for f in faces]
    return "\n".join(out) + "\n"


def stl_binary(n, start=0):
    verts, faces, _ = subset(n, start)
    tris = triangles(faces)
    b = b"cathlab fuzz seed from arch-to-cow vessels.obj (MIT)".ljust(80, b" ")
    b += struct.pack("<I", len(tris))
    for t in tris:
        b += struct.pack("<3f", 0, 0, 0)
        for i in t:
            b += struct.pack("<3f", *verts[i])
        b += b"\0\0"
    return b


def stl_ascii(n, start=0, name="arch"):
    verts, faces, _ = subset(n, start)
    out = ["solid " + name]
    for t in triangles(faces):
        out += ["  facet normal 0 0 1", "    outer loop"]
        out += ["      vertex %.6e %.6e %.6e" % verts[i] for i in t]
        out += ["    endloop", "  endfacet"]
    return "\n".join(out + ["endsolid " + name]) + "\n"


def ply(n, fmt, start=0, double=False, list_type="uchar int"):
    verts, faces, _ = subset(n, start)
    scalar = "double" if double else "float"
    head = ["ply", "format %s 1.0" % fmt, "comment arch-to-cow subset (MIT)",
            "element vertex %d" % len(verts)] + ["property %s %s" % (scalar, a) for a in "xyz"]
    head += ["element face %d" % len(faces), "property list %s vertex_indices" % list_type,
             "end_header"]
    text = "\n".join(head) + "\n"
    if fmt == "ascii":
        body = "".join("%.6f %.6f %.6f\n" % v for v in verts)
        body += "".join("%d %s\n" % (len(f), " ".join(map(str, f))) for f in faces)
        return text + body
    e = "<" if fmt == "binary_little_endian" else ">"
    codes = {"uchar": "B", "uint8": "B", "int": "i", "int32": "i", "uint": "I", "ushort": "H",
             "short": "h"}
    count_t, index_t = (codes[x] for x in list_type.split())
    body = b"".join(struct.pack(e + ("3d" if double else "3f"), *v) for v in verts)
    body += b"".join(struct.pack(e + count_t + index_t * len(f), len(f), *f) for f in faces)
    return text.encode() + body


def surfaces():
    write("stl", "binary_12.stl", stl_binary(12))
    write("stl", "binary_200.stl", stl_binary(200, 1000))
    write("stl", "ascii_6.stl", stl_ascii(6))
    write("stl", "ascii_40.stl", stl_ascii(40, 2000, "vessels"))
    write("stl", "ascii_unnamed_4.stl", stl_ascii(4, 3000, "").replace("solid \n", "solid\n"))
    write("obj", "normals_20.obj", obj_text(20))
    write("obj", "normals_300.obj", obj_text(300, 1500))
    write("obj", "plain_10.obj", obj_text(10, 3000, normals=False))
    write("ply", "ascii_15.ply", ply(15, "ascii"))
    write("ply", "le_float_40.ply", ply(40, "binary_little_endian", 500))
    write("ply", "be_double_20.ply", ply(20, "binary_big_endian", 900, double=True))
    write("ply", "le_uchar_uint_10.ply", ply(10, "binary_little_endian", 2500,
                                            list_type="uint8 uint"))
    write("ply", "ascii_300.ply", ply(300, "ascii", 100))


# --- centerlines: the real Slicer markups, shortened; SWC and VTP lines from them ---------

def markups(name):
    return json.load(open(path("data/anatomy/arch-to-cow/centerlines/%s.mrk.json" % name)))


def shorten(doc, n, step=1):
    doc = json.loads(json.dumps(doc))
    for m in doc["markups"]:
        keep = list(range(0, len(m["controlPoints"]), step))[:n]
        m["controlPoints"] = [m["controlPoints"][i] for i in keep]
        for meas in m.get("measurements", []):
            if "controlPointValues" in meas:
                meas["controlPointValues"] = [meas["controlPointValues"][i] for i in keep]
    return doc


def curve(name, n, step):
    m = shorten(markups(name), n, step)["markups"][0]
    radius = next(x["controlPointValues"] for x in m["measurements"] if x["name"] == "Radius")
    return [tuple(p["position"]) for p in m["controlPoints"]], radius


def centerlines():
    for name, n, step in [("LVA", 12, 10), ("RCCA", 30, 5), ("LCCA", 6, 30)]:
        write("slicer", "%s_%d.mrk.json" % (name, n), json.dumps(shorten(markups(name), n, step),
                                                             indent=2))
    # Two curves in one file, the second in RAS coordinates.
    two = shorten(markups("RVA"), 10, 15)
    other = shorten(markups("LVA"), 8, 20)["markups"][0]
    other["coordinateSystem"] = "RAS"
    other["name"] = "LVA"
    two["markups"].append(other)
    write("slicer", "two_curves.mrk.json", json.dumps(two))

    # SWC (mm): one chain, and a tree of two chains sharing a root.
    def swc(chains, scale=1.0):
        lines = ["# cathlab fuzz seed: arch-to-cow centerlines (MIT)", "# id type x y z r parent"]
        next_id = 1
        root = None
        for pts, rad in chains:
            parent = root if root is not None else -1
            for k, (p, r) in enumerate(zip(pts, rad)):
                if k == 0 and root is not None:
                    continue
                lines.append("%d 3 %.3f %.3f %.3f %.3f %d" % (next_id, p[0] * scale, p[1] * scale,
                                                             p[2] * scale, r * scale, parent))
                if root is None:
                    root = next_id
                parent = next_id
                next_id += 1
        return "\n".join(lines) + "\n"

    lcca = curve("LCCA", 25, 6)
    rcca = curve("RCCA", 25, 6)
    write("swc", "chain_mm.swc", swc([lcca]))
    write("swc", "tree_mm.swc", swc([lcca, (rcca[0][-15:], rcca[1][-15:])]))
    write("swc", "chain_short.swc", swc([curve("LVA", 10, 20)]))
    return lcca, rcca


# --- VTP: the real (zlib, appended) file and small ones in each encoding -------------------

def vtk_block(data, zlib_on, header_u64):
    w = "<Q" if header_u64 else "<I"
    if not zlib_on:
        return struct.pack(w, len(data)) + data
    c = zlib.compress(data)
    return struct.pack(w, 1) + struct.pack(w, len(data)) + struct.pack(w, len(data)) + \
        struct.pack(w, len(c)) + c


def vtp(points, polys, lines, radius, fmt, zlib_on=False, header_u64=False):
    """fmt: ascii, binary (inline base64), appended-raw, appended-base64."""
    arrays = []  # (section, name, vtk type, struct code, values, components)
    if radius is not None:
        arrays.append(("PointData", "Radius", "Float32", "f", radius, 1))
    arrays.append(("Points", "Points", "Float64" if fmt != "binary" else "Float32",
                   "d" if fmt != "binary" else "f", [c for p in points for c in p], 3))
    for section, cells in (("Lines", lines), ("Polys", polys)):
        conn, offs, o = [], [], 0
        for c in cells:
            conn += c
            o += len(c)
            offs.append(o)
        arrays.append((section, "connectivity", "Int64", "q", conn, 1))
        arrays.append((section, "offsets", "Int64", "q", offs, 1))
    appended = b""
    xml_arrays = {}
    for section, name, vtype, code, values, comps in arrays:
        attrs = 'type="%s" Name="%s"%s' % (vtype, name,
                                          ' NumberOfComponents="3"' if comps == 3 else "")
        raw = struct.pack("<%d%s" % (len(values), code), *values)
        if fmt == "ascii":
            body = " ".join(repr(v) for v in values)
            xml = '<DataArray %s format="ascii">%s</DataArray>' % (attrs, body)
        elif fmt == "binary":
            body = base64.b64encode(vtk_block(raw, zlib_on, header_u64)).decode()
            xml = '<DataArray %s format="binary">%s</DataArray>' % (attrs, body)
        else:
            block = vtk_block(raw, zlib_on, header_u64)
            if fmt == "appended-base64":
                block = base64.b64encode(block)
            xml = '<DataArray %s format="appended" offset="%d"/>' % (attrs, len(appended))
            appended += block
        xml_arrays.setdefault(section, []).append(xml)
    head = '<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" header_type="%s"%s>' % (
        "UInt64" if header_u64 else "UInt32",
        ' compressor="vtkZLibDataCompressor"' if zlib_on else "")
    out = ['<?xml version="1.0"?>', head, "<PolyData>",
           '<Piece NumberOfPoints="%d" NumberOfLines="%d" NumberOfPolys="%d">' % (
               len(points), len(lines), len(polys))]
    for section in ("PointData", "Points", "Lines", "Polys"):
        out.append("<%s>" % section + "".join(xml_arrays.get(section, [])) + "</%s>" % section)
    out += ["</Piece>", "</PolyData>"]
    text = "\n".join(out).encode()
    if fmt.startswith("appended"):
        enc = "raw" if fmt == "appended-raw" else "base64"
        text += b'\n<AppendedData encoding="%s">\n_' % enc.encode() + appended + \
            b"\n</AppendedData>"
    return text + b"\n</VTKFile>\n"


def vtps(lcca, rcca):
    shutil.copy(path("data/anatomy/arch-to-cow-open/vessels_open.vtp"),
                os.path.join(OUT, "vtp", "vessels_open_real.vtp"))
    verts, faces, _ = subset(30, 800)
    tri_verts, tri_faces, _ = subset(60, 1600)
    pts, rad = lcca
    line = [list(range(len(pts)))]
    write("vtp", "ascii_surface.vtp", vtp(verts, faces, [], None, "ascii"))
    write("vtp", "ascii_lines_radius.vtp", vtp(list(pts), [], line, list(rad), "ascii"))
    write("vtp", "binary_zlib_u32.vtp", vtp(tri_verts, tri_faces, [], None, "binary", True))
    write("vtp", "binary_raw_u64.vtp", vtp(verts, faces, [], None, "binary", False, True))
    write("vtp", "appended_raw_zlib.vtp", vtp(tri_verts, tri_faces, [], None, "appended-raw",
                                              True))
    write("vtp", "appended_base64_u64.vtp", vtp(list(rcca[0]), [], [list(range(len(rcca[0])))],
                                                list(rcca[1]), "appended-base64", False, True))
    both = list(pts) + list(verts)
    n = len(pts)
    write("vtp", "surface_and_line_zlib.vtp",
          vtp(both, [[i + n for i in f] for f in faces], line, None, "appended-raw", True, True))


# --- volumes: crops of the real MetaImage and NIfTI files ---------------------------------

def metaimage():
    b = open(path("data/ct/aorta.mha"), "rb").read()
    end = b.index(b"ElementDataFile = LOCAL\n") + len(b"ElementDataFile = LOCAL\n")
    header, data = b[:end].decode(), zlib.decompress(b[end:])
    fields = dict(l.split(" = ", 1) for l in header.strip().split("\n"))
    nx, ny, nz = map(int, fields["DimSize"].split())
    vals = struct.unpack("<%df" % (nx * ny * nz), data)

    def crop(x0, y0, z0, sx, sy, sz):
        return [vals[(z0 + k) * nx * ny + (y0 + j) * nx + x0 + i]
                for k in range(sz) for j in range(sy) for i in range(sx)]

    def mha(dims, voxels, etype="MET_FLOAT", compressed=False, msb=False, datafile="LOCAL",
            extra=""):
        code = {"MET_FLOAT": "f", "MET_SHORT": "h", "MET_UCHAR": "B", "MET_DOUBLE": "d"}[etype]
        if code in "hB":
            voxels = [max(-32768 if code == "h" else 0, min(32767 if code == "h" else 255,
                                                            int(v))) for v in voxels]
        raw = struct.pack((">" if msb else "<") + "%d%s" % (len(voxels), code), *voxels)
        body = zlib.compress(raw) if compressed else raw
        h = ["ObjectType = Image", "NDims = 3", "BinaryData = True",
             "BinaryDataByteOrderMSB = %s" % ("True" if msb else "False"),
             "CompressedData = %s" % ("True" if compressed else "False")]
        if compressed:
            h.append("CompressedDataSize = %d" % len(body))
        h += ["TransformMatrix = %s" % fields["TransformMatrix"], "Offset = %s" % fields["Offset"],
              "CenterOfRotation = 0 0 0", "AnatomicalOrientation = LPI",
              "ElementSpacing = %s" % fields["ElementSpacing"],
              "DimSize = %d %d %d" % dims, "ElementType = %s" % etype]
        if extra:
            h.append(extra)
        h.append("ElementDataFile = %s" % datafile)
        head = ("\n".join(h) + "\n").encode()
        if datafile == "LOCAL":
            return head + body
        return head + NEXT_FILE + body

    small = crop(70, 180, 15, 6, 5, 3)
    write("metaimage", "float_raw.mha", mha((6, 5, 3), small))
    write("metaimage", "float_zlib.mha", mha((6, 5, 3), small, compressed=True))
    write("metaimage", "short_msb.mha", mha((6, 5, 3), small, "MET_SHORT", msb=True))
    write("metaimage", "uchar_zlib_4x4x2.mha", mha((4, 4, 2), crop(60, 200, 20, 4, 4, 2),
                                                   "MET_UCHAR", compressed=True))
    write("metaimage", "double_origin.mha", mha((3, 3, 2), crop(75, 190, 16, 3, 3, 2),
                                                "MET_DOUBLE", extra="ElementSize = 1 1 2"))
    # A .mhd header and its data file: the input's second part is written as f.raw.
    write("metaimage", "header_and_raw.mhd", mha((6, 5, 3), small, datafile="f.raw"))
    write("metaimage", "header_and_zlib.mhd", mha((6, 5, 3), small, compressed=True,
                                                  datafile="f.raw"))


def nifti():
    def load(p):
        b = open(p, "rb").read()
        return gzip.decompress(b) if b[:2] == b"\x1f\x8b" else b

    def crop(b, size, at, big_endian=False):
        dims = struct.unpack("<8h", b[40:56])
        bitpix = struct.unpack("<h", b[72:74])[0] // 8
        off = int(struct.unpack("<f", b[108:112])[0])
        nx, ny = dims[1], dims[2]
        sx, sy, sz = size
        out = bytearray()
        for k in range(sz):
            for j in range(sy):
                start = off + (((at[2] + k) * ny + at[1] + j) * nx + at[0]) * bitpix
                out += b[start:start + sx * bitpix]
        h = bytearray(b[:348])
        h[40:56] = struct.pack("<8h", 3, sx, sy, sz, 1, 1, 1, 1)
        h[108:112] = struct.pack("<f", 352.0)
        data = bytes(h) + b"\0\0\0\0" + bytes(out)
        if big_endian:
            data = swap_nifti(data, bitpix)
        return data

    def swap_nifti(data, bitpix):
        """The same image with every header field and voxel byte-swapped."""
        h = bytearray(data[:348])
        for off, n, code in [(0, 1, "i"), (32, 1, "i"), (36, 1, "h"), (40, 8, "h"), (56, 3, "f"), (68, 1, "h"), (70, 1, "h"),
                             (72, 1, "h"), (74, 1, "h"), (76, 8, "f"), (108, 1, "f"),
                             (112, 1, "f"), (116, 1, "f"), (120, 1, "h"), (124, 4, "f"),
                             (140, 2, "i"), (252, 1, "h"), (254, 1, "h"), (256, 6, "f"),
                             (280, 12, "f")]:
            size = struct.calcsize(code)
            vals = struct.unpack("<%d%s" % (n, code), h[off:off + n * size])
            h[off:off + n * size] = struct.pack(">%d%s" % (n, code), *vals)
        body = bytearray(data[352:])
        if bitpix > 1:
            for i in range(0, len(body), bitpix):
                body[i:i + bitpix] = body[i:i + bitpix][::-1]
        return bytes(h) + data[348:352] + bytes(body)

    template = load(os.path.join(SHARED, "ct/rorden-ct-template/scct.nii"))
    ct = load(os.path.join(SHARED, "ct/totalsegmentator-example/example_ct.nii.gz"))
    write("nifti", "uint8_slope_6x6x4.nii", crop(template, (6, 6, 4), (40, 50, 40)))
    write("nifti", "uint8_slope_6x6x4_be.nii", crop(template, (6, 6, 4), (40, 50, 40), True))
    write("nifti", "int32_5x4x3.nii", crop(ct, (5, 4, 3), (60, 50, 56)))
    write("nifti", "int32_5x4x3.nii.gz", gzip.compress(crop(ct, (5, 4, 3), (60, 50, 56)), 9,
                                                       mtime=0))
    write("nifti", "int32_8x8x2_be.nii.gz", gzip.compress(crop(ct, (8, 8, 2), (40, 40, 60), True),
                                                          9, mtime=0))


# --- DICOM: two-slice series cropped from the real JPEG 2000 CT ---------------------------

def dicom():
    import numpy as np
    import pydicom
    from pydicom.encaps import encapsulate
    from pydicom.uid import (DeflatedExplicitVRLittleEndian, ExplicitVRLittleEndian,
                             ImplicitVRLittleEndian, JPEG2000Lossless, RLELossless)
    from PIL import Image

    files = sorted(glob.glob(path("data/ct/totalsegmentator-example/dicom/*")))
    slices = [pydicom.dcmread(f) for f in files[:3]]

    def cropped(ds, size, syntax):
        px = ds.pixel_array[200:200 + size, 240:240 + size].astype(np.uint16)
        ds = copy.deepcopy(ds)
        ds.Rows, ds.Columns = px.shape
        ds.file_meta.TransferSyntaxUID = syntax
        if syntax == JPEG2000Lossless:
            out = io.BytesIO()
            Image.fromarray(px).save(
                out, format="JPEG2000", irreversible=False, no_jp2=True)
            ds.PixelData = encapsulate([out.getvalue()])
            ds["PixelData"].VR = "OB"
        elif syntax == RLELossless:
            ds.PixelData = px.tobytes()
            ds["PixelData"].VR = "OW"
            ds.compress(RLELossless, px, encoding_plugin="pydicom")
        else:
            ds.PixelData = px.tobytes()
            ds["PixelData"].VR = "OW"
        # Keep the header small: drop private and non-essential groups.
        for tag in [t for t in ds.keys() if t.is_private or t.group in (0x0009, 0x0019, 0x0029)]:
            del ds[tag]
        out = io.BytesIO()
        implicit = syntax == ImplicitVRLittleEndian
        ds.save_as(out, enforce_file_format=True, implicit_vr=implicit, little_endian=True) \
            if syntax not in (JPEG2000Lossless, RLELossless, DeflatedExplicitVRLittleEndian) \
            else ds.save_as(out, enforce_file_format=True)
        return out.getvalue()

    for syntax, name, size in [(JPEG2000Lossless, "j2k_lossless", 16),
                               (ExplicitVRLittleEndian, "explicit_le", 8),
                               (ImplicitVRLittleEndian, "implicit_le", 8),
                               (DeflatedExplicitVRLittleEndian, "deflated", 8),
                               (RLELossless, "rle", 12)]:
        parts = [cropped(s, size, syntax) for s in slices[:2]]
        write("dicom", "%s_2slices.dcm" % name, NEXT_FILE.join(parts))
    write("dicom", "j2k_3slices.dcm", NEXT_FILE.join(cropped(s, 8, JPEG2000Lossless)
                                                     for s in slices))
    write("dicom", "explicit_le_1slice.dcm", cropped(slices[0], 8, ExplicitVRLittleEndian))


# --- scenes and the device catalogue -----------------------------------------------------

def scenes():
    for p in sorted(glob.glob(path("scenes/*.toml"))):
        shutil.copy(p, os.path.join(OUT, "scene", os.path.basename(p)))
    for name in ("arch_to_cow_lcca", "stroke_m1_from_access"):
        doc = tomllib.load(open(path("scenes/%s.toml" % name), "rb"))
        write("scene", name + ".json", json.dumps(doc, indent=1))


def devices():
    text = open(path("server/physics/devices/catalogue.toml")).read()
    write("devices", "catalogue.toml", text)
    # Each of the first devices alone (with the comments before it).
    chunks = text.split("[[device]]")
    for i, chunk in enumerate(chunks[1:4]):
        write("devices", "device_%d.toml" % i, "[[device]]" + chunk)


def main():
    if os.path.isdir(OUT):
        for t in os.listdir(OUT):
            if os.path.isdir(os.path.join(OUT, t)):
                shutil.rmtree(os.path.join(OUT, t))
    for t in ("stl", "obj", "ply", "vtp", "swc", "slicer", "metaimage", "nifti", "dicom",
              "scene", "devices"):
        os.makedirs(os.path.join(OUT, t), exist_ok=True)
    surfaces()
    lcca, rcca = centerlines()
    vtps(lcca, rcca)
    metaimage()
    nifti()
    dicom()
    scenes()
    devices()
    for t in sorted(os.listdir(OUT)):
        d = os.path.join(OUT, t)
        if os.path.isdir(d):
            sizes = [os.path.getsize(os.path.join(d, f)) for f in os.listdir(d)]
            print("%-10s %2d files, largest %6d bytes" % (t, len(sizes), max(sizes)))


if __name__ == "__main__":
    sys.exit(main())
