#!/usr/bin/env python3
"""Checks tests/release_only.txt against the release build's test list: every pattern must name
at least one registered GoogleTest case. A pattern left behind by a renamed test would let that
test back into the sanitizer run (minutes each, the reason the list exists); a mistyped one would
leave out nothing. And every case labelled `release-only` (a program `fr_test(... RELEASE_ONLY)`
declares, which the sanitizer build does not build) must match a pattern: a case added to such a
program that the list does not name would otherwise never run under the sanitizers.
Usage: check_release_only.py LIST BUILD_DIR"""
import fnmatch
import json
import subprocess
import sys


def patterns(path):
    out = []
    with open(path, encoding="utf-8") as f:
        for number, line in enumerate(f, 1):
            text = line.split("#", 1)[0].strip()
            if text:
                out.append((number, text))
    return out


def labels(test):
    for prop in test.get("properties", []):
        if prop.get("name") == "LABELS":
            return prop.get("value") or []
    return []


def main():
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        return 2
    listing = subprocess.run(["ctest", "--test-dir", sys.argv[2], "--show-only=json-v1"],
                             check=True, capture_output=True, text=True).stdout
    tests = json.loads(listing)["tests"]
    names = [t["name"] for t in tests]
    cases = [n for n in names if "." in n]
    if len(cases) < 100:
        print(f"only {len(cases)} GoogleTest cases registered in {sys.argv[2]}: not the release build?")
        return 1
    stale = [(n, p) for n, p in patterns(sys.argv[1]) if not any(fnmatch.fnmatchcase(c, p) for c in cases)]
    for number, pattern in stale:
        print(f"{sys.argv[1]}:{number}: '{pattern}' names no test case of the release build")
    listed = [p for _, p in patterns(sys.argv[1])]
    unlisted = [t["name"] for t in tests if "release-only" in labels(t)
                and not any(fnmatch.fnmatchcase(t["name"], p) for p in listed)]
    for name in unlisted:
        print(f"{name}: its program is RELEASE_ONLY (not built with the sanitizers) but {sys.argv[1]} "
              "does not name it; add it there, or take RELEASE_ONLY off its fr_test")
    if stale or unlisted:
        return 1
    print(f"{len(patterns(sys.argv[1]))} patterns, each naming at least one of {len(cases)} cases")
    return 0


if __name__ == "__main__":
    sys.exit(main())
