#!/usr/bin/env python3
"""End-to-end test of the "Face Reenact" OBS source in the real OBS Studio program.

Starts Debian's `obs` on a private Xvfb display with a temporary HOME holding: our plugin (a
link to the build tree's plugin folder, OBS's per-user plugin layout), a profile (160x120 canvas),
a scene collection whose only scene shows a "Face Reenact" source playing a small synthetic
recording, and obs-websocket v5 enabled. A minimal websocket client (Python standard library
only) identifies with protocol v5 and asks for GetSourceScreenshot of the source; the PNG it
returns must have the recording's size and match one of its frames.

Then the plugin's obs-websocket vendor "face-reenact" (docs/obs-source.md), through
CallVendorRequest: GetStatus of that source says what it does (raw input), ListSources lists the
Face Reenact sources, bad requests (an unknown source name, a scene, no sourceName, a raw-mode
source to calibrate) answer a clear error and OBS goes on. A second source, "Tracked"
(pass-through on a 320x240 recording, a face the tracker calibrates on), is calibrated remotely
once it tracks: Calibrate answers ok, its counter moves and GetStatus then says "calibrating".
Last, the raw source's recording is removed with SetInputSettings: the vendor event StateChanged
(the client subscribes to vendor events) says it has no input.

Exit status: 0 passed, 1 failed (the reason is printed), 77 skipped (obs or Xvfb missing, or OBS
cannot start at all on this machine; the reason is printed).

  obs_websocket_e2e.py --cli FACE_REENACT --plugin-dir BUILD/obs-plugins/face-reenact --work DIR
"""
import argparse
import base64
import hashlib
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
import zlib

SKIP = 77
WIDTH, HEIGHT, FRAMES = 160, 120, 12
SOURCE_NAME = "Face"
TRACKED_NAME = "Tracked"  # pass-through on a 320x240 recording: calibrates, then tracks
TRACKED_SIZE, TRACKED_FRAMES = (320, 240), 60
VENDOR = "face-reenact"


class Failure(Exception):
    pass


class Skip(Exception):
    pass


# --- PNG decoding (8-bit grey/RGB/RGBA, not interlaced: what OpenCV and Qt write) -------------
def decode_png(data):
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise Failure("not a PNG")
    pos, idat, width = 8, b"", 0
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", body)
            if depth != 8 or interlace != 0 or colour not in (0, 2, 6):
                raise Failure(f"unsupported PNG (depth {depth}, colour type {colour}, interlace {interlace})")
            channels = {0: 1, 2: 3, 6: 4}[colour]
        elif kind == b"IDAT":
            idat += body
        elif kind == b"IEND":
            break
    raw = zlib.decompress(idat)
    stride = width * channels
    rows, prev = [], bytearray(stride)
    for y in range(height):
        base = y * (stride + 1)
        filt, line = raw[base], bytearray(raw[base + 1:base + 1 + stride])
        for i in range(stride):
            a = line[i - channels] if i >= channels else 0
            b = prev[i]
            c = prev[i - channels] if i >= channels else 0
            if filt == 1:
                line[i] = (line[i] + a) & 255
            elif filt == 2:
                line[i] = (line[i] + b) & 255
            elif filt == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif filt == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                line[i] = (line[i] + pred) & 255
        rows.append(line)
        prev = line
    # Luma per pixel (BT.601 weights), enough to compare pictures.
    luma = []
    for line in rows:
        for x in range(width):
            px = line[x * channels:x * channels + channels]
            luma.append(px[0] if channels == 1 else 0.299 * px[0] + 0.587 * px[1] + 0.114 * px[2])
    return width, height, luma


def mean_abs_diff(a, b):
    return sum(abs(x - y) for x, y in zip(a, b)) / len(a)


def stddev(values):
    m = sum(values) / len(values)
    return (sum((v - m) ** 2 for v in values) / len(values)) ** 0.5


# --- a minimal websocket client (RFC 6455): text frames, masking, ping/pong ---------------------
class WebSocket:
    def __init__(self, host, port, timeout):
        self.events = []  # op 5 messages received while waiting for answers
        self.sock = socket.create_connection((host, port), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        request = (f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                   f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                   f"Sec-WebSocket-Protocol: obswebsocket.json\r\n\r\n")
        self.sock.sendall(request.encode())
        response = b""
        while b"\r\n\r\n" not in response:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise ConnectionError("connection closed during the handshake")
            response += chunk
        head, self.buffer = response.split(b"\r\n\r\n", 1)
        if b" 101 " not in head.split(b"\r\n")[0]:
            raise ConnectionError("handshake refused: " + head.split(b"\r\n")[0].decode(errors="replace"))
        accept = base64.b64encode(hashlib.sha1((key + "258EAFA5-E914-47DA-95CA-C5AB0DC85B11").encode()).digest())
        if accept not in head:
            raise ConnectionError("bad Sec-WebSocket-Accept")

    def _read(self, n):
        while len(self.buffer) < n:
            chunk = self.sock.recv(1 << 20)
            if not chunk:
                raise ConnectionError("connection closed")
            self.buffer += chunk
        out, self.buffer = self.buffer[:n], self.buffer[n:]
        return out

    def _send_frame(self, opcode, payload):
        header = bytes([0x80 | opcode])
        n = len(payload)
        if n < 126:
            header += bytes([0x80 | n])
        elif n < 65536:
            header += bytes([0x80 | 126]) + struct.pack(">H", n)
        else:
            header += bytes([0x80 | 127]) + struct.pack(">Q", n)
        mask = os.urandom(4)
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.sock.sendall(header + mask + masked)

    def send_json(self, obj):
        self._send_frame(0x1, json.dumps(obj).encode())

    def recv_json(self):
        message = b""
        while True:
            b0, b1 = self._read(2)
            opcode, n = b0 & 0x0F, b1 & 0x7F
            if n == 126:
                n = struct.unpack(">H", self._read(2))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._read(8))[0]
            mask = self._read(4) if b1 & 0x80 else None
            payload = self._read(n)
            if mask:
                payload = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
            if opcode == 0x9:  # ping
                self._send_frame(0xA, payload)
                continue
            if opcode == 0x8:
                raise ConnectionError("server closed the connection: " + payload[2:].decode(errors="replace"))
            message += payload
            if b0 & 0x80:
                return json.loads(message)

    def close(self):
        try:
            self._send_frame(0x8, struct.pack(">H", 1000))
        except OSError:
            pass
        self.sock.close()


# --- OBS set-up ---------------------------------------------------------------------------------
def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def write_config(home, plugin_dir, recording, tracked_recording, port):
    config = os.path.join(home, ".config", "obs-studio")
    os.makedirs(os.path.join(config, "plugins"))
    os.symlink(os.path.abspath(plugin_dir), os.path.join(config, "plugins", "face-reenact"))
    with open(os.path.join(config, "global.ini"), "w") as f:
        f.write("[General]\nFirstRun=true\nEnableAutoUpdates=false\nLastVersion=486539266\n\n"
                "[Basic]\nProfile=FRTest\nProfileDir=FRTest\nSceneCollection=FRTest\nSceneCollectionFile=FRTest\n"
                "ConfigOnNewProfile=false\n\n"
                f"[OBSWebSocket]\nFirstLoad=false\nServerEnabled=true\nServerPort={port}\nAlertsEnabled=false\n"
                "AuthRequired=false\nServerPassword=unused\n")
    profile = os.path.join(config, "basic", "profiles", "FRTest")
    os.makedirs(profile)
    with open(os.path.join(profile, "basic.ini"), "w") as f:
        f.write(f"[General]\nName=FRTest\n\n[Video]\nBaseCX={WIDTH}\nBaseCY={HEIGHT}\nOutputCX={WIDTH}\n"
                f"OutputCY={HEIGHT}\nFPSType=0\nFPSCommon=30\n\n[Output]\nMode=Simple\n")
    scenes = os.path.join(config, "basic", "scenes")
    os.makedirs(scenes)
    collection = {
        "name": "FRTest",
        "current_scene": "Scene",
        "current_program_scene": "Scene",
        "scene_order": [{"name": "Scene"}],
        "sources": [
            {"id": "scene", "versioned_id": "scene", "name": "Scene", "enabled": True, "flags": 0,
             "settings": {"id_counter": 1, "custom_size": False, "items": [
                 {"name": SOURCE_NAME, "id": 1, "visible": True, "locked": False, "rot": 0.0,
                  "pos": {"x": 0.0, "y": 0.0}, "scale": {"x": 1.0, "y": 1.0}, "align": 5,
                  "bounds_type": 0, "bounds_align": 0, "bounds": {"x": 0.0, "y": 0.0}},
                 {"name": TRACKED_NAME, "id": 2, "visible": False, "locked": False, "rot": 0.0,
                  "pos": {"x": 0.0, "y": 0.0}, "scale": {"x": 1.0, "y": 1.0}, "align": 5,
                  "bounds_type": 0, "bounds_align": 0, "bounds": {"x": 0.0, "y": 0.0}}]}},
            {"id": "face_reenact_source", "versioned_id": "face_reenact_source", "name": SOURCE_NAME,
             "enabled": True, "flags": 0,
             "settings": {"target_kind": "recording", "target_path": recording, "source_kind": "none",
                          "mode": "raw"}},
            {"id": "face_reenact_source", "versioned_id": "face_reenact_source", "name": TRACKED_NAME,
             "enabled": True, "flags": 0,
             "settings": {"target_kind": "recording", "target_path": tracked_recording, "source_kind": "none",
                          "mode": "passthrough"}},
        ],
    }
    with open(os.path.join(scenes, "FRTest.json"), "w") as f:
        json.dump(collection, f)
    return config


def start_xvfb(work):
    xvfb = shutil.which("Xvfb")
    if not xvfb:
        raise Skip("Xvfb is not installed (apt-get install xvfb)")
    read_fd, write_fd = os.pipe()
    proc = subprocess.Popen([xvfb, "-displayfd", str(write_fd), "-screen", "0", "1280x720x24", "-nolisten", "tcp",
                             "-noreset"], pass_fds=[write_fd], stdout=subprocess.DEVNULL,
                            stderr=open(os.path.join(work, "xvfb.log"), "w"))
    os.close(write_fd)
    number = b""
    deadline = time.time() + 20
    while time.time() < deadline:
        c = os.read(read_fd, 1)
        if not c or c == b"\n":
            break
        number += c
    os.close(read_fd)
    if not number:
        proc.kill()
        raise Skip("Xvfb did not start (see xvfb.log)")
    return proc, ":" + number.decode()


def stop(proc, timeout=20):
    if proc and proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def obs_log(config):
    logs = os.path.join(config, "logs")
    if not os.path.isdir(logs):
        return ""
    files = sorted(os.listdir(logs))
    return open(os.path.join(logs, files[-1]), errors="replace").read() if files else ""


def request(ws, kind, data, request_id):
    ws.send_json({"op": 6, "d": {"requestType": kind, "requestId": request_id, "requestData": data}})
    while True:
        msg = ws.recv_json()
        if msg.get("op") == 5:  # an event that arrived meanwhile: kept for the checks
            ws.events.append(msg["d"])
        if msg.get("op") == 7 and msg["d"].get("requestId") == request_id:
            return msg["d"]


def vendor(ws, request_type, data, request_id):
    """CallVendorRequest to our vendor: (obs-websocket's requestStatus, our responseData)."""
    call = {"vendorName": VENDOR, "requestType": request_type}
    if data is not None:  # (obs-websocket 5.1 refuses an empty requestData object)
        call["requestData"] = data
    d = request(ws, "CallVendorRequest", call, request_id)
    return d["requestStatus"], d.get("responseData", {}).get("responseData", {})


def expect_error(ws, request_type, data, request_id, words):
    status, answer = vendor(ws, request_type, data, request_id)
    if not status.get("result"):
        raise Failure(f"{request_type} {data}: obs-websocket failed the call: {status}")
    if answer.get("ok") is not False or words not in answer.get("error", ""):
        raise Failure(f"{request_type} {data}: expected an error saying '{words}', got {answer}")
    print(f"{request_type} {json.dumps(data)} -> error: {answer['error']}")


def wait_status(ws, name, accept, timeout, what, config, interval=0.2):
    """GetStatus of `name` until accept(answer); the answers seen on the way (state changes)."""
    deadline, seen, i, answer = time.time() + timeout, [], 0, {}
    while time.time() < deadline:
        i += 1
        status, answer = vendor(ws, "GetStatus", {"sourceName": name}, f"w{what}{i}")
        if not status.get("result") or not answer.get("ok"):
            raise Failure(f"GetStatus {name}: {status} {answer}")
        if not seen or seen[-1]["state"] != answer["state"]:
            seen.append(answer)
            print(f"  {name}: {answer['state']}: {answer['status']}")
        if accept(answer):
            return answer, seen
        if answer["state"] == "unchanged" and "no face model" in answer["status"]:
            raise Skip(f"{name} cannot track: {answer['status']} (set FACE_REENACT_MODEL)")
        time.sleep(interval)
    raise Failure(f"{name} never {what} within {timeout} s; last status {answer}\n" + obs_log(config)[-3000:])


def check_vendor(ws, config):
    """The plugin's obs-websocket vendor: status, calibration, and clear errors on bad input."""
    status, answer = vendor(ws, "GetStatus", {"sourceName": SOURCE_NAME}, "g1")
    if not status.get("result"):
        raise Failure(f"CallVendorRequest GetStatus failed (vendor not registered?): {status}\n" + obs_log(config)[-3000:])
    print("GetStatus", SOURCE_NAME, "->", answer)
    if not answer.get("ok") or answer.get("sourceName") != SOURCE_NAME:
        raise Failure(f"GetStatus {SOURCE_NAME}: {answer}")
    if answer.get("state") != "raw" or not answer.get("status", "").startswith("Raw input"):
        raise Failure(f"GetStatus {SOURCE_NAME} does not say what the source does (raw input): {answer}")
    if answer.get("mode") != "raw" or not answer.get("targetOpen") or answer.get("framesOut", 0) <= 0:
        raise Failure(f"GetStatus {SOURCE_NAME}: unexpected fields {answer}")
    if answer.get("wantsOpenMouth") is not False:  # raw input tracks nothing: no still is wanted
        raise Failure(f"GetStatus {SOURCE_NAME}: wantsOpenMouth should be false in raw mode: {answer}")

    status, answer = vendor(ws, "ListSources", None, "l1")
    names = sorted(item.get("sourceName") for item in answer.get("sources", []))
    print("ListSources ->", names)
    if not answer.get("ok") or names != sorted([SOURCE_NAME, TRACKED_NAME]):
        raise Failure(f"ListSources: {status} {answer}")

    expect_error(ws, "GetStatus", {"sourceName": "No such source"}, "e1", "no source named 'No such source'")
    expect_error(ws, "Calibrate", {"sourceName": "No such source"}, "e2", "no source named")
    expect_error(ws, "GetStatus", {"sourceName": "Scene"}, "e3", "is not a Face Reenact source")
    expect_error(ws, "Calibrate", {"sourceName": "Scene"}, "e4", "is not a Face Reenact source")
    expect_error(ws, "GetStatus", {"source": SOURCE_NAME}, "e5", "missing field 'sourceName'")
    expect_error(ws, "Calibrate", None, "e5b", "missing field 'sourceName'")
    expect_error(ws, "Calibrate", {"sourceName": 42}, "e6", "missing field 'sourceName'")
    expect_error(ws, "Calibrate", {"sourceName": SOURCE_NAME}, "e7", "raw mode")
    status, _ = vendor(ws, "NoSuchRequest", None, "e8")
    if status.get("result"):
        raise Failure(f"an unknown vendor request succeeded: {status}")
    print("NoSuchRequest ->", status.get("comment"))
    if request(ws, "GetVersion", {}, "alive")["requestStatus"].get("result") is not True:
        raise Failure("OBS stopped answering after the bad requests")

    # Remote calibration of a tracking source: the same as its Calibrate button.
    tracking, _ = wait_status(ws, TRACKED_NAME, lambda a: a["state"] == "tracking", 200, "tracking", config)
    before = tracking["calibrationsRequested"]
    events_before = len(ws.events)
    status, answer = vendor(ws, "Calibrate", {"sourceName": TRACKED_NAME}, "c1")
    print("Calibrate", TRACKED_NAME, "->", answer)
    if not status.get("result") or not answer.get("ok"):
        raise Failure(f"Calibrate {TRACKED_NAME}: {status} {answer}")
    if answer.get("calibrationsRequested") != before + 1:
        raise Failure(f"Calibrate {TRACKED_NAME}: the calibration counter did not move ({before} before): {answer}")
    # Polled every 20 ms: collecting the calibration's 5 frames alone takes 1/6 s at 30 fps.
    calibrating, _ = wait_status(ws, TRACKED_NAME, lambda a: a["state"] == "calibrating", 30, "calibrating", config,
                                 interval=0.02)
    if not calibrating["status"].startswith("Calibrating") or calibrating["tracking"] != "calibrating":
        raise Failure(f"GetStatus after Calibrate: the status does not say calibrating: {calibrating}")

    # The vendor event StateChanged announces changes without polling. The source looks at its
    # state twice a second, so a calibration shorter than that may pass unannounced: a lasting
    # change, made through obs-websocket's own SetInputSettings (the raw source's recording
    # removed), must be announced.
    missing = "/nonexistent/face-reenact/recording"
    changed = request(ws, "SetInputSettings", {"inputName": SOURCE_NAME, "inputSettings": {"target_path": missing}},
                      "set1")
    if not changed["requestStatus"].get("result"):
        raise Failure(f"SetInputSettings failed: {changed['requestStatus']}")
    deadline, changes = time.time() + 10, []
    while time.time() < deadline:
        changes = [(e["eventData"]["eventData"].get("sourceName"), e["eventData"]["eventData"].get("state"),
                    e["eventData"]["eventData"].get("status"))
                   for e in ws.events[events_before:] if e.get("eventType") == "VendorEvent"
                   and e["eventData"].get("vendorName") == VENDOR and e["eventData"].get("eventType") == "StateChanged"]
        if any(name == SOURCE_NAME and state == "no_input" for name, state, _ in changes):
            break
        request(ws, "GetVersion", {}, f"pump{time.time()}")
        time.sleep(0.2)
    print("StateChanged events since Calibrate:", [(name, state) for name, state, _ in changes])
    no_input = [status for name, state, status in changes if name == SOURCE_NAME and state == "no_input"]
    if not no_input or missing not in no_input[0]:
        raise Failure(f"no StateChanged event saying {SOURCE_NAME} lost its recording: {changes}")
    status, answer = vendor(ws, "GetStatus", {"sourceName": SOURCE_NAME}, "g2")
    if answer.get("state") != "no_input":
        raise Failure(f"GetStatus after the recording was removed: {answer}")


def run(args):
    obs = shutil.which(args.obs)
    if not obs:
        raise Skip("the obs program is not installed (apt-get install obs-studio)")
    if not os.path.isfile(os.path.join(args.plugin_dir, "bin", "64bit", "face-reenact.so")):
        raise Failure(f"the plugin is not built: {args.plugin_dir}/bin/64bit/face-reenact.so")
    if os.path.exists(args.work):
        shutil.rmtree(args.work)
    os.makedirs(args.work)

    recording = os.path.join(args.work, "recording")
    model = os.environ.get("FR_MODEL", "")
    synth = subprocess.run([args.cli, "synth", "--size", f"{WIDTH}x{HEIGHT}", "--frames", str(FRAMES), "--seed", "7",
                            "--quiet", "--out", recording] + (["--model", model] if model else []),
                           capture_output=True, text=True)
    if synth.returncode != 0:
        raise Failure("face-reenact synth failed: " + synth.stderr)
    tracked_recording = os.path.join(args.work, "recording-320")
    synth = subprocess.run([args.cli, "synth", "--size", "%dx%d" % TRACKED_SIZE, "--frames", str(TRACKED_FRAMES),
                            "--seed", "7", "--quiet", "--out", tracked_recording] + (["--model", model] if model else []),
                           capture_output=True, text=True)
    if synth.returncode != 0:
        raise Failure("face-reenact synth failed: " + synth.stderr)
    frames = []
    for name in sorted(os.listdir(os.path.join(recording, "color"))):
        w, h, luma = decode_png(open(os.path.join(recording, "color", name), "rb").read())
        frames.append(luma)
    if len(frames) != FRAMES or (w, h) != (WIDTH, HEIGHT):
        raise Failure(f"unexpected recording: {len(frames)} frames of {w}x{h}")

    home = os.path.join(args.work, "home")
    port = free_port()
    config = write_config(home, args.plugin_dir, recording, tracked_recording, port)
    xvfb, display = start_xvfb(args.work)
    env = dict(os.environ, HOME=home, DISPLAY=display, QT_QPA_PLATFORM="xcb", LIBGL_ALWAYS_SOFTWARE="1",
               XDG_CONFIG_HOME=os.path.join(home, ".config"))
    env.pop("WAYLAND_DISPLAY", None)
    obs_out = open(os.path.join(args.work, "obs.stdout"), "w")
    proc = subprocess.Popen([obs, "--collection", "FRTest", "--profile", "FRTest", "--disable-updater",
                             "--disable-shutdown-check", "--websocket_port", str(port)],
                            cwd=os.path.dirname(obs), env=env, stdout=obs_out, stderr=subprocess.STDOUT)
    ws = None
    try:
        deadline = time.time() + args.start_timeout
        while ws is None:
            if proc.poll() is not None:
                raise Skip(f"obs exited with status {proc.returncode} before its websocket came up; its output:\n"
                           + open(os.path.join(args.work, "obs.stdout"), errors="replace").read()[-3000:])
            if time.time() > deadline:
                raise Skip(f"obs did not open its websocket within {args.start_timeout} s; log:\n"
                           + obs_log(config)[-3000:])
            try:
                ws = WebSocket("127.0.0.1", port, timeout=30)
            except OSError:
                time.sleep(0.5)
        hello = ws.recv_json()
        if hello.get("op") != 0:
            raise Failure(f"expected Hello, got {hello}")
        print("obs-websocket", hello["d"].get("obsWebSocketVersion"), "rpc", hello["d"].get("rpcVersion"))
        # Vendor events only (EventSubscription::Vendors): the plugin's StateChanged.
        ws.send_json({"op": 1, "d": {"rpcVersion": 1, "eventSubscriptions": 1 << 9}})
        identified = ws.recv_json()
        if identified.get("op") != 2:
            raise Failure(f"expected Identified, got {identified}")

        version = request(ws, "GetVersion", {}, "v")
        print("OBS", version["responseData"].get("obsVersion"), "image formats",
              version["responseData"].get("supportedImageFormats"))
        kinds = request(ws, "GetInputKindList", {"unversioned": True}, "k")
        if "face_reenact_source" not in kinds["responseData"].get("inputKinds", []):
            raise Failure("OBS did not load the plugin: face_reenact_source is not an input kind\n" + obs_log(config)[-3000:])

        # The source needs a moment to deliver its first frames: retry until the picture is not blank.
        best, shot = None, None
        deadline = time.time() + 60
        attempt = 0
        while time.time() < deadline:
            attempt += 1
            response = request(ws, "GetSourceScreenshot", {"sourceName": SOURCE_NAME, "imageFormat": "png"}, f"s{attempt}")
            status = response["requestStatus"]
            if not status.get("result"):
                raise Failure(f"GetSourceScreenshot failed: {status}")
            data = response["responseData"]["imageData"]
            png = base64.b64decode(data.split(",", 1)[1])
            w, h, luma = decode_png(png)
            if stddev(luma) > 10:
                shot = (w, h, luma, png)
                break
            time.sleep(0.5)
        if shot is None:
            raise Failure("every screenshot of the source was blank\n" + obs_log(config)[-3000:])
        w, h, luma, png = shot
        open(os.path.join(args.work, "screenshot.png"), "wb").write(png)
        if (w, h) != (WIDTH, HEIGHT):
            raise Failure(f"screenshot is {w}x{h}, the recording is {WIDTH}x{HEIGHT}")
        diffs = [mean_abs_diff(luma, f) for f in frames]
        best = min(diffs)
        shifted = [frames[0][min(i + 6, len(frames[0]) - 1)] for i in range(len(frames[0]))]
        shifted_diff = min(mean_abs_diff(shifted, f) for f in frames)
        print(f"screenshot {w}x{h}: luma std {stddev(luma):.1f}, mean abs difference to the closest recording frame "
              f"{best:.2f} (a picture shifted by 6 px: {shifted_diff:.2f})")
        if best > 3.0:
            raise Failure(f"the screenshot does not match the recording (closest frame differs by {best:.2f})")
        if shifted_diff < best + 1.0:
            raise Failure("the comparison cannot tell the recording from a shifted copy")
        log = obs_log(config)
        if "[face-reenact]" not in log:
            raise Failure("the OBS log has no [face-reenact] lines")
        print("plugin log lines:", [l for l in log.splitlines() if "[face-reenact]" in l][:4])
        if "obs-websocket vendor 'face-reenact' registered" not in log:
            raise Failure("the OBS log does not say the obs-websocket vendor was registered")
        check_vendor(ws, config)
        if proc.poll() is not None:
            raise Failure(f"obs exited ({proc.returncode}) during the vendor requests")
    finally:
        if ws:
            ws.close()
        stop(proc)
        stop(xvfb)
        obs_out.close()
    return 0


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cli", required=True, help="the face-reenact program (makes the recording)")
    parser.add_argument("--plugin-dir", required=True, help="build tree's obs-plugins/face-reenact")
    parser.add_argument("--work", required=True, help="scratch folder (emptied first)")
    parser.add_argument("--obs", default="obs", help="the obs program")
    parser.add_argument("--start-timeout", type=float, default=120, help="seconds to wait for OBS to start")
    args = parser.parse_args()
    try:
        return run(args)
    except Skip as e:
        print("SKIP:", e)
        return SKIP
    except Failure as e:
        print("FAIL:", e)
        return 1


if __name__ == "__main__":
    sys.exit(main())
