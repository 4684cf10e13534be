"""handcap's ChArUco stereo calibration against OpenCV's own Python ChArUco calibration.

For each seed, `handcap synth` renders a synthetic capture of a 10x7 ChArUco board (10 mm
squares, 7.5 mm DICT_5X5_100 markers) seen by two virtual webcams: 20 board pairs, every
other one with the board partly out of view, and the rig's ground truth (truth/rig.yml: K1,
D1, K2, D2, R, T with p_right = R p_left + T in mm). The same 20 pairs (not the reference
pair) are then calibrated twice:

* handcap: `handcap calibrate WORK/seedN/calib`, its result read back from the YAML it writes;
* OpenCV-Python, as a user would write it from OpenCV's ChArUco tutorials:
  `cv2.aruco.CharucoDetector(board).detectBoard` on each image, `cv2.calibrateCamera` per
  camera (object points `board.getChessboardCorners()[ids]`, default flags), then
  `cv2.stereoCalibrate` on each pair's common corners (pairs with fewer than 8 skipped;
  `CALIB_USE_INTRINSIC_GUESS`, criteria count 100 / eps 1e-9 as handcap uses).

Both are scored against the truth: focal length (largest relative error of fx, fy of either
camera, %), principal point (largest distance from the true one of either camera, px),
baseline (relative error of |T|, %), rotation (angle of R_est^T R_true, degrees), with the
RMS reprojection error each reports, the pairs it used and its wall time (handcap's includes
its diagnostics and plots; OpenCV's its image loading and detection). OpenCV's board frame
has its origin at the board's outer corner, handcap's at the first inner corner: only the
boards' poses differ, not the rig. One Markdown table is printed.

    bash scripts/bench-charuco.sh [--seeds 2020,1,2] [--work DIR] [--clean] [--reuse]
"""

import argparse
import glob
import os
import subprocess
import sys
import time

import cv2
import numpy as np

SQUARES = (10, 7)
SQUARE_MM = 10.0
MARKER_MM = 7.5
DICTIONARY = "DICT_5X5_100"
MIN_VIEW_CORNERS = 4  # as OpenCV's calibrate_camera_charuco tutorial: more than 3 corners
MIN_PAIR_CORNERS = 8
STEREO_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-9)


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default="2020,1,2", help="comma-separated synth seeds")
    p.add_argument("--work", default="target/bench-charuco", help="work directory")
    p.add_argument("--handcap", default="target/release/handcap", help="handcap binary")
    p.add_argument("--clean", action="store_true", help="render ideal frames (synth --clean)")
    p.add_argument("--reuse", action="store_true",
                   help="keep a seed's earlier render if WORK/seedN/truth/rig.yml exists")
    return p.parse_args()


def run(cmd, log_path):
    """Run a command, its output to log_path; its wall time (s). Exits on failure."""
    start = time.perf_counter()
    with open(log_path, "w") as log:
        result = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT)
    elapsed = time.perf_counter() - start
    if result.returncode != 0:
        sys.exit(f"failed ({result.returncode}): {' '.join(cmd)}; see {log_path}")
    return elapsed


def render(args, seed_dir, seed):
    """Render the synthetic capture of one seed (unless --reuse finds one)."""
    if args.reuse and os.path.exists(os.path.join(seed_dir, "truth", "rig.yml")):
        return
    cmd = [args.handcap, "synth", "--out", seed_dir, "--seed", str(seed),
           "--board", f"charuco:{SQUARES[0]}x{SQUARES[1]}", "--square-mm", f"{SQUARE_MM:g}",
           "--marker-mm", f"{MARKER_MM:g}", "--dictionary", DICTIONARY]
    if args.clean:
        cmd.append("--clean")
    os.makedirs(seed_dir, exist_ok=True)
    print(f"seed {seed}: {' '.join(cmd)}", file=sys.stderr)
    run(cmd, os.path.join(seed_dir, "synth.log"))


def read_rig(path):
    """K1, K2, R, T (and rms_px, views_used when present) of an OpenCV YAML rig file."""
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        sys.exit(f"cannot read {path}")
    rig = {key: fs.getNode(key).mat() for key in ("K1", "K2", "R", "T")}
    rms = fs.getNode("rms_px")
    rig["rms"] = rms.real() if not rms.empty() else None
    views = fs.getNode("views_used")
    rig["pairs"] = views.size() if not views.empty() else None
    fs.release()
    return rig


def run_handcap(args, seed_dir):
    """handcap's calibration of the seed's pairs: the rig it wrote and its wall time."""
    out = os.path.join(seed_dir, "handcap.yml")
    cmd = [args.handcap, "calibrate", os.path.join(seed_dir, "calib"), "--out", out]
    elapsed = run(cmd, os.path.join(seed_dir, "handcap.log"))
    rig = read_rig(out)
    rig["time"] = elapsed
    return rig


def make_board(legacy):
    """OpenCV's ChArUco board of the renders, in mm."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, DICTIONARY))
    board = cv2.aruco.CharucoBoard(SQUARES, SQUARE_MM, MARKER_MM, dictionary)
    board.setLegacyPattern(legacy)
    return board


def detect_all(board, grays):
    """ChArUco corners of each image: {name: (corners Nx2, ids N)} for those with any."""
    detector = cv2.aruco.CharucoDetector(board)
    found = {}
    for name, gray in grays.items():
        corners, ids, _, _ = detector.detectBoard(gray)
        if ids is not None and len(ids) > 0:
            found[name] = (corners.reshape(-1, 2).astype(np.float32), ids.ravel())
    return found


def calibrate_camera(board, detections, names, size):
    """cv2.calibrateCamera on one camera's images: K, D."""
    chess = board.getChessboardCorners()
    obj, img = [], []
    for name in names:
        if name in detections and len(detections[name][1]) >= MIN_VIEW_CORNERS:
            corners, ids = detections[name]
            obj.append(chess[ids].astype(np.float32))
            img.append(corners)
    _, K, D, _, _ = cv2.calibrateCamera(obj, img, size, None, None)
    return K, D


def corners_of(detection, ids):
    """The detected image points of the given corner ids, in their order."""
    corners, found = detection
    index = {corner_id: i for i, corner_id in enumerate(found)}
    return corners[[index[i] for i in ids]]


def run_opencv(seed_dir):
    """OpenCV-Python's ChArUco stereo calibration of the seed's pairs (not the ref pair)."""
    calib = os.path.join(seed_dir, "calib")
    start = time.perf_counter()
    lefts = sorted(p for p in glob.glob(os.path.join(calib, "left_*.jpg"))
                   + glob.glob(os.path.join(calib, "left_*.png")) if "_ref." not in p)
    stems = [os.path.basename(p).split("_", 1)[1] for p in lefts]
    grays = {}
    for stem, left in zip(stems, lefts):
        grays["left_" + stem] = cv2.imread(left, cv2.IMREAD_GRAYSCALE)
        grays["right_" + stem] = cv2.imread(left.replace("left_", "right_"), cv2.IMREAD_GRAYSCALE)
    size = grays["left_" + stems[0]].shape[::-1]

    # OpenCV 4.6 and 4.10 lay out a board with an odd number of rows alike; should that
    # not hold, the legacy (pre-4.7) pattern is tried.
    for legacy in (False, True):
        board = make_board(legacy)
        detections = detect_all(board, grays)
        if detections:
            break
    else:
        sys.exit(f"OpenCV found no ChArUco corners in {calib}")

    K1, D1 = calibrate_camera(board, detections, ["left_" + s for s in stems], size)
    K2, D2 = calibrate_camera(board, detections, ["right_" + s for s in stems], size)

    chess = board.getChessboardCorners()
    obj, img1, img2 = [], [], []
    for stem in stems:
        left, right = detections.get("left_" + stem), detections.get("right_" + stem)
        if left is None or right is None:
            continue
        common = np.intersect1d(left[1], right[1])
        if len(common) < MIN_PAIR_CORNERS:
            continue
        obj.append(chess[common].astype(np.float32))
        img1.append(corners_of(left, common))
        img2.append(corners_of(right, common))
    rms, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(
        obj, img1, img2, K1, D1, K2, D2, size,
        flags=cv2.CALIB_USE_INTRINSIC_GUESS, criteria=STEREO_CRITERIA)
    return {"K1": K1, "K2": K2, "R": R, "T": T, "rms": rms, "pairs": len(obj),
            "time": time.perf_counter() - start,
            "pattern": "legacy" if legacy else "default"}


def errors(est, truth):
    """The estimate's errors against the truth."""
    focal, pp = 0.0, 0.0
    for key in ("K1", "K2"):
        k, t = est[key], truth[key]
        focal = max(focal, *(abs(k[i, i] - t[i, i]) / t[i, i] * 100 for i in (0, 1)))
        pp = max(pp, float(np.hypot(k[0, 2] - t[0, 2], k[1, 2] - t[1, 2])))
    base_true = np.linalg.norm(truth["T"])
    baseline = abs(np.linalg.norm(est["T"]) - base_true) / base_true * 100
    rvec, _ = cv2.Rodrigues(est["R"].T @ truth["R"])
    rotation = float(np.degrees(np.linalg.norm(rvec)))
    return {"focal": focal, "pp": pp, "baseline": baseline, "rotation": rotation}


COLUMNS = [("pairs used", "pairs", "{:.0f}"), ("RMS px", "rms", "{:.3f}"),
           ("max focal err %", "focal", "{:.3f}"), ("max pp err px", "pp", "{:.2f}"),
           ("baseline err %", "baseline", "{:.3f}"), ("rotation err °", "rotation", "{:.4f}"),
           ("time s", "time", "{:.2f}")]


def table_row(label, tool, row):
    cells = ["—" if row.get(key) is None else fmt.format(row[key]) for _, key, fmt in COLUMNS]
    return f"| {label} | {tool} | " + " | ".join(cells) + " |"


def print_table(results):
    """results: [(seed, tool, row)]; one Markdown table with a mean row per tool."""
    print("| seed | tool | " + " | ".join(title for title, _, _ in COLUMNS) + " |")
    print("|---|---|" + "---:|" * len(COLUMNS))
    for seed, tool, row in results:
        print(table_row(str(seed), tool, row))
    for tool in dict.fromkeys(tool for _, tool, _ in results):
        rows = [row for _, t, row in results if t == tool]
        mean = {}
        for _, key, _ in COLUMNS:
            values = [row[key] for row in rows if row.get(key) is not None]
            mean[key] = float(np.mean(values)) if values else None
        print(table_row("**mean**", tool, mean))


def main():
    args = parse_args()
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    results, patterns = [], []
    for seed in seeds:
        seed_dir = os.path.join(args.work, f"seed{seed}")
        render(args, seed_dir, seed)
        truth = read_rig(os.path.join(seed_dir, "truth", "rig.yml"))
        for tool, runner in (("handcap", lambda: run_handcap(args, seed_dir)),
                             ("OpenCV-Python", lambda: run_opencv(seed_dir))):
            est = runner()
            est.update(errors(est, truth))
            results.append((seed, tool, est))
            if "pattern" in est:
                patterns.append(f"seed {seed}: {est['pattern']}")
    print(f"OpenCV-Python {cv2.__version__}, numpy {np.__version__}; "
          f"ChArUco {SQUARES[0]}x{SQUARES[1]} {SQUARE_MM:g}/{MARKER_MM:g} mm {DICTIONARY}"
          f"{', --clean renders' if args.clean else ''}; "
          f"board pattern that detected: {', '.join(patterns)}\n")
    print_table(results)


if __name__ == "__main__":
    main()
