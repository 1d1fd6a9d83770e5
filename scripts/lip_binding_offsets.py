#!/usr/bin/env python3
"""Where dlib and the 300-W annotation put the lip points, against the model's bindings.

Measures, on frontal faces, the offset of each iBUG point from the model's bound vertex: the
points (dlib on the first frames of the shared clips, and the .pts annotation of the shared photos)
are brought onto the model's mean face, seen from the front, by the 2D similarity that fits the
tracker's nose and mouth points best; the median of each point's remainder over faces is its
offset (model millimetres, x to the person's left, y down). For the points asked for, it then
picks the model vertex nearest to binding + offset on the same surface (within 2.5 mm in depth;
inner upper-lip points among the vertices jawOpen does not move, inner lower-lip points among
those it moves; midline points on the midline) and prints its hm08 index for data/ibug68_landmarks.json, the person's left side
mirrored from the right (docs/face-model.md, "Landmarks").

Usage: scripts/lip_binding_offsets.py [--points 50,51,61,67] [--clips webcam_talking_640x480.wmv,...]
Run from the repository with the release build in build/ (its face-reenact and face model).
Plain Python: no packages beyond the standard library.
"""
import argparse, json, math, os, statistics, subprocess, sys, tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, '..', 'shared', 'data')
FIT_POINTS = [27, 28, 29, 30, 31, 32, 34, 35] + list(range(48, 68))  # the tracker's E_lan points
MIRROR = {48: 54, 49: 53, 50: 52, 55: 59, 56: 58, 60: 64, 61: 63, 65: 67}


def run(cli, *args):
    return subprocess.run([cli, *args], check=True, capture_output=True, text=True).stdout


def obj_vertices(path):
    return [tuple(1000.0 * float(x) for x in line.split()[1:4]) for line in open(path) if line.startswith('v ')]


def similarity_to_model(points, model):
    """points (ibug -> complex image position) brought onto model (ibug -> complex, mm)."""
    mz = sum(model[i] for i in FIT_POINTS) / len(FIT_POINTS)
    pz = sum(points[i] for i in FIT_POINTS) / len(FIT_POINTS)
    a = sum((points[i] - pz) * (model[i] - mz).conjugate() for i in FIT_POINTS) / sum(abs(model[i] - mz) ** 2 for i in FIT_POINTS)
    return {i: (p - pz) / a + mz for i, p in points.items()}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--points', default='50,51,61,67', help='right-side (and midline) points to re-bind')
    ap.add_argument('--clips', default='webcam_talking_640x480.wmv,liveportrait_d0.mp4,liveportrait_d14.mp4')
    ap.add_argument('--frames', type=int, default=10, help='frames per clip')
    args = ap.parse_args()
    cli = os.path.join(ROOT, 'build', 'bin', 'face-reenact')
    if not os.path.isdir(DATA):
        sys.exit('no ../shared/data beside this clone: the clips and photos are measured there')
    tmp = tempfile.mkdtemp(prefix='fr-lip-offsets-')
    info = json.loads(run(cli, 'model', 'info', '--json'))
    bound = {l['ibug']: l['vertex'] for l in info['landmark_vertices']}
    run(cli, 'model', 'export', '--out', os.path.join(tmp, 'mean.obj'))
    run(cli, 'model', 'export', '--out', os.path.join(tmp, 'jaw.obj'), '--expression', 'jawOpen=0.3')
    mean, jaw = obj_vertices(os.path.join(tmp, 'mean.obj')), obj_vertices(os.path.join(tmp, 'jaw.obj'))
    model = {i: complex(mean[v][0], -mean[v][1]) for i, v in bound.items()}  # front view, y down

    faces = []
    for clip in args.clips.split(','):
        out = os.path.join(tmp, clip + '.json')
        run(cli, 'landmarks', '--input', os.path.join(DATA, 'videos', clip), '--max-frames', str(args.frames), '--out', out)
        for frame in json.load(open(out))['frames']:
            for face in (frame.get('faces') or ([frame] if 'points' in frame else []))[:1]:
                pts = [complex(*(p[:2] if isinstance(p, list) else (p['x'], p['y']))) for p in face['points']]
                if len(pts) == 68:
                    faces.append(('dlib ' + clip, pts))
    for dirpath, _, files in os.walk(os.path.join(DATA, 'faces-68')):
        for f in files:
            if not f.endswith('.pts'):
                continue
            pts = []
            for line in open(os.path.join(dirpath, f)):
                t = line.split()
                if len(t) == 2:
                    try:
                        pts.append(complex(float(t[0]), float(t[1])))
                    except ValueError:
                        pass
            if len(pts) == 68:
                faces.append(('annotation', pts))
    remainders = {i: [] for i in range(68)}
    for _, pts in faces:
        on_model = similarity_to_model(dict(enumerate(pts)), model)
        for i in range(68):
            remainders[i].append(on_model[i] - model[i])
    print(f'{len(faces)} faces; median offset of each point from its binding (mm, x to the person\'s left, y down)')
    offset = {}
    for i in range(27, 68):
        offset[i] = complex(statistics.median(r.real for r in remainders[i]), statistics.median(r.imag for r in remainders[i]))
        print(f'  {i:2d}{"*" if i in FIT_POINTS else " "} {offset[i].real:+5.1f} {offset[i].imag:+5.1f}')

    moves = [mean[v][1] - jaw[v][1] for v in range(len(mean))]  # > 0: moves down with jawOpen
    chosen = {}
    for i in (int(p) for p in args.points.split(',')):
        v0 = bound[i]
        x0, y0, z0 = mean[v0]
        tx, ty = x0 + offset[i].real, y0 - offset[i].imag
        candidates = []
        for v, (x, y, z) in enumerate(mean):
            if abs(z - z0) > 2.5 or math.hypot(x - x0, y - y0) > 10:
                continue
            if i in (65, 66, 67) and moves[v] < 0.5 * moves[v0]:
                continue
            if i in (61, 62, 63) and moves[v] > 0.3:
                continue
            if i in (51, 57, 62, 66) and abs(x) > 0.5:  # midline points stay on the midline
                continue
            candidates.append((math.hypot(x - tx, y - ty), v))
        miss, v = min(candidates)
        chosen[i] = v
        if i in MIRROR or i in {b: a for a, b in MIRROR.items()}:
            partner = MIRROR.get(i) or {b: a for a, b in MIRROR.items()}[i]
            x, y, z = mean[v]
            chosen[partner] = min(range(len(mean)), key=lambda u: (mean[u][0] + x) ** 2 + (mean[u][1] - y) ** 2 + (mean[u][2] - z) ** 2)
        print(f'  {i}: model vertex {v0} -> {v} ({miss:.1f} mm from binding + offset)')
    base = info['base_vertex']
    print('hm08 bindings for data/ibug68_landmarks.json:')
    for i in sorted(chosen):
        print(f'  {{"ibug": {i}, "vertex": {base[chosen[i]]}}}  (was {base[bound[i]]})')


if __name__ == '__main__':
    main()
