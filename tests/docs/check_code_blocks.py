#!/usr/bin/env python3
"""ctest Docs.CodeBlocks: the fenced code blocks of the documentation run as written.

    python3 tests/docs/check_code_blocks.py --build BUILD_DIR --work WORK_DIR
            [--cxx COMPILER] [--launcher LAUNCHER] [--python PYTHON] FILE.md ...

- ```cpp blocks are complete programs: each is compiled against the build
  tree's otfp library (a CMake project with find_package(otfp), otfp_DIR =
  BUILD_DIR, warnings as errors; otfp::mpi linked too where the build has
  it) and run from an empty temporary directory. A block that includes a
  header of otfp::mpi (mpi_headers()) is skipped in a build without it.
- ```python blocks are run with PYTHON (default /usr/bin/python3) from an
  empty temporary directory with PYTHONPATH = BUILD_DIR/python.
- Either must exit with status 0 and leave nothing behind in the directory it
  ran from (a reader runs them anywhere, the repository included).
- Other blocks (shell commands, TOML, output) are listed as not run.
"""
import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile

FENCE = re.compile(r"^```\s*([\w+-]*)\s*$")
CPP = {"cpp", "c++", "cxx"}
PYTHON = {"python", "py", "python3"}


ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def mpi_headers():
    """The public headers of the component otfp::mpi (src/mpi): those named
    after one of its sources, and otfp/tao.hpp and otfp/mpi.hpp."""
    names = {"tao", "mpi"}
    mpi_src = os.path.join(ROOT, "src", "mpi")
    for f in os.listdir(mpi_src):
        stem, ext = os.path.splitext(f)
        if ext == ".cpp" and os.path.exists(os.path.join(ROOT, "include", "otfp", stem + ".hpp")):
            names.add(stem)
    return {f"otfp/{n}.hpp" for n in names}


def needs_mpi(code, headers):
    """Whether a C++ block includes one of `headers` (mpi_headers())."""
    return any(f'"{h}"' in code or f"<{h}>" in code for h in headers)


def blocks(path):
    """(first line number, language, code) of every fenced block."""
    out, lang, start, lines = [], None, 0, []
    with open(path) as f:
        for number, line in enumerate(f, 1):
            m = FENCE.match(line.rstrip("\n"))
            if lang is None and m:
                lang, start, lines = m.group(1).lower(), number + 1, []
            elif lang is not None and line.rstrip("\n") == "```":
                out.append((start, lang, "".join(lines)))
                lang = None
            elif lang is not None:
                lines.append(line)
    if lang is not None:
        sys.exit(f"check_code_blocks.py: {path}:{start - 1}: unterminated ``` block")
    return out


def run_in_empty_dir(cmd, env, label, timeout):
    """Runs cmd in a fresh directory; returns a problem or ''."""
    cwd = tempfile.mkdtemp(prefix="otfp_doc_block_")
    try:
        r = subprocess.run(cmd, cwd=cwd, env=env, timeout=timeout, stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True)
        print(f"--- {label}: output\n{r.stdout.rstrip()}")
        if r.returncode != 0:
            return f"exit status {r.returncode}"
        left = sorted(os.listdir(cwd))
        if left:
            return f"left {', '.join(left)} in the directory it ran from"
        return ""
    except subprocess.TimeoutExpired:
        return f"did not finish within {timeout} s"
    finally:
        shutil.rmtree(cwd, ignore_errors=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", required=True)
    ap.add_argument("--work", required=True)
    ap.add_argument("--cxx", default="")
    ap.add_argument("--launcher", default="")
    ap.add_argument("--python", default="/usr/bin/python3" if os.path.exists("/usr/bin/python3") else sys.executable)
    ap.add_argument("files", nargs="+")
    args = ap.parse_args()
    build, work = os.path.abspath(args.build), os.path.abspath(args.work)
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(os.path.join(work, "src"))

    with open(os.path.join(build, "CMakeCache.txt")) as f:
        with_mpi = "OTFP_WITH_MPI:BOOL=ON" in f.read()
    cpp, py, skipped = [], [], []
    mpi = mpi_headers()
    for path in args.files:
        name = os.path.basename(path)
        for line, lang, code in blocks(path):
            label = f"{name}:{line} ({lang or 'plain'})"
            if lang in CPP and needs_mpi(code, mpi) and not with_mpi:
                skipped.append(label + " (needs otfp::mpi)")
            elif lang in CPP:
                cpp.append((label, f"{os.path.splitext(name)[0]}_{line}", code))
            elif lang in PYTHON:
                py.append((label, code))
            else:
                skipped.append(label)
    problems = []

    if cpp:
        cmake = ["cmake_minimum_required(VERSION 3.20)", "project(otfp_doc_blocks LANGUAGES CXX)",
                 "set(CMAKE_CXX_STANDARD 20)", "set(CMAKE_CXX_STANDARD_REQUIRED ON)",
                 "find_package(otfp REQUIRED)"]
        for label, target, code in cpp:
            if not re.search(r"\bint\s+main\s*\(", code):
                problems.append(f"{label}: not a complete program (no main): a reader cannot compile it as written")
                continue
            with open(os.path.join(work, "src", target + ".cpp"), "w") as f:
                f.write(code)
            cmake += [f"add_executable({target} src/{target}.cpp)",
                      f"target_link_libraries({target} PRIVATE otfp::otfp)",
                      # docs/distributed.md's TAO programs: where the build has the component
                      f"if(TARGET otfp::mpi)\n  target_link_libraries({target} PRIVATE otfp::mpi)\nendif()",
                      f"target_compile_options({target} PRIVATE -Wall -Wextra -Werror)"]
        with open(os.path.join(work, "CMakeLists.txt"), "w") as f:
            f.write("\n".join(cmake) + "\n")
        configure = ["cmake", "-S", work, "-B", os.path.join(work, "build"), "-DCMAKE_BUILD_TYPE=Release",
                     f"-Dotfp_DIR={build}"]
        if args.cxx:
            configure.append(f"-DCMAKE_CXX_COMPILER={args.cxx}")
        if args.launcher:
            configure.append(f"-DCMAKE_CXX_COMPILER_LAUNCHER={args.launcher}")
        subprocess.run(configure, check=True, stdout=subprocess.DEVNULL)
        for label, target, code in cpp:
            if not os.path.exists(os.path.join(work, "src", target + ".cpp")):
                continue
            r = subprocess.run(["cmake", "--build", os.path.join(work, "build"), "--target", target, "-j", "2"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            if r.returncode != 0:
                print(r.stdout)
                problems.append(f"{label}: does not compile against the library (output above)")
                continue
            problem = run_in_empty_dir([os.path.join(work, "build", target)], os.environ.copy(), label, 600)
            if problem:
                problems.append(f"{label}: {problem}")
            else:
                print(f"ok: {label}")

    if py:
        module = os.path.join(build, "python")
        if not os.path.isdir(os.path.join(module, "otfp")):
            skipped += [f"{label}: the Python module is not built" for label, _ in py]
            py = []
        else:
            env = os.environ.copy()
            env["PYTHONPATH"] = module
            for i, (label, code) in enumerate(py):
                script = os.path.join(work, f"block_{i}.py")
                with open(script, "w") as f:
                    f.write(code)
                problem = run_in_empty_dir([args.python, script], env, label, 600)
                if problem:
                    problems.append(f"{label}: {problem}")
                else:
                    print(f"ok: {label}")

    for label in skipped:
        print(f"not run: {label}")
    if problems:
        print("\n".join(["", "FAILED:"] + problems))
        sys.exit(1)
    print(f"all {len(cpp)} C++ and {len(py)} Python blocks ran")


if __name__ == "__main__":
    main()
