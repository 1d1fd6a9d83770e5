#!/usr/bin/env python3
"""Serves browser_camera.html on 127.0.0.1 and writes what the page POSTs to /result.

    browser_camera_server.py PORT RESULT_FILE [TIMEOUT_S]

The page's frames (PNG data URLs in "pngs") are written beside RESULT_FILE as RESULT-N.png, whose
names replace the data in the JSON. Runs inside the test VM (guest_webcam_checks.sh). getUserMedia needs a secure context, which
http://127.0.0.1 is and a file:// page in headless Chromium is not reliably. Exits 0 once a result
was written, 1 when none came within TIMEOUT_S (default 300).
"""
import base64
import http.server
import json
import os
import sys
import threading

PAGE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "browser_camera.html")


def main():
    port, result_file = int(sys.argv[1]), sys.argv[2]
    timeout_s = float(sys.argv[3]) if len(sys.argv) > 3 else 300.0
    done = threading.Event()

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            if self.path.split("?")[0] != "/browser_camera.html":
                self.send_error(404)
                return
            with open(PAGE, "rb") as f:
                body = f.read()
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def do_POST(self):
            if self.path != "/result":
                self.send_error(404)
                return
            body = self.rfile.read(int(self.headers.get("Content-Length", "0")))
            try:
                result = json.loads(body)
                prefix = "data:image/png;base64,"
                names = []
                for n, png in enumerate(result.get("pngs", [])):
                    if not png.startswith(prefix):
                        continue
                    png_file = f"{os.path.splitext(result_file)[0]}-{n}.png"
                    with open(png_file, "wb") as f:
                        f.write(base64.b64decode(png[len(prefix):]))
                    names.append(os.path.basename(png_file))
                result["pngs"] = names
            except (ValueError, AttributeError) as e:
                result = {"error": f"the page posted no JSON object: {e}", "posted": body[:200].decode("latin-1")}
            with open(result_file + ".tmp", "w") as f:
                json.dump(result, f, indent=1)
            os.replace(result_file + ".tmp", result_file)
            self.send_response(204)
            self.end_headers()
            done.set()

        def log_message(self, fmt, *args):
            sys.stderr.write("server: " + (fmt % args) + "\n")

    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    ok = done.wait(timeout_s)
    server.shutdown()
    if not ok:
        sys.stderr.write(f"server: no result within {timeout_s:.0f} s\n")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
