# SPDX-License-Identifier: Apache-2.0
"""
astrometry.net, blind, on our spot lists: an independent check of solves that have no reference.

For each image: our centroids (`solve`'s defaults) go to `solve-field` as an x/y list with
only the pixel-scale range (no position hint); its best match (log-odds, matches, conflicts)
and pointing are printed beside ours. Needs the Debian packages astrometry.net and
astrometry-data-tycho2-10-19 (not a dependency of the project).

    python -m bench.anet_spot_check openstartracker_img7 openstartracker_img8 --scale 14.5 17
"""
from __future__ import annotations

import argparse
import math
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench import bench_realdata as bench  # noqa: E402

MATCH = re.compile(r"log-odds ratio ([\d.]+) .*?(\d+) match, (\d+) conflict")
CENTRE = re.compile(r"RA,Dec = \(([\d.]+),([-\d.]+)\), pixel scale ([\d.]+) arcsec/pix")


def anet_best(log: str) -> dict | None:
    """Return the best-scoring match in a solve-field log: log-odds, matches, conflicts, RA, Dec [deg]."""
    best = None
    lines = log.splitlines()
    for k, line in enumerate(lines):
        found = MATCH.search(line)
        if not found:
            continue
        centre = next((CENTRE.search(x) for x in lines[k:k + 6] if CENTRE.search(x)), None)
        row = {"log_odds": float(found.group(1)), "matches": int(found.group(2)), "conflicts": int(found.group(3)),
               "ra_deg": float(centre.group(1)) if centre else None,
               "dec_deg": float(centre.group(2)) if centre else None}
        if best is None or row["log_odds"] > best["log_odds"]:
            best = row
    return best


def wcs_centre(path: Path, width: int, height: int):
    """Return the ICRS unit vector of the image centre pixel ((W-1)/2, (H-1)/2, 0-based) through a WCS file."""
    import numpy as np
    from astropy.io import fits
    from astropy.wcs import WCS

    ra, dec = WCS(fits.getheader(path)).all_pix2world([(width - 1) / 2.0], [(height - 1) / 2.0], 0)
    ra, dec = np.radians(ra[0]), np.radians(dec[0])
    return np.array([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])


def _arcsec(a, b) -> float:
    import numpy as np

    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b))) * 3600.0)


def _apart(centre, ours: dict, code: int) -> str:
    import numpy as np

    if code != 0:
        return "(ours not solved)"
    ra, dec = np.radians(ours["ra_deg"]), np.radians(ours["dec_deg"])
    return f"{_arcsec(centre, np.array([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])):.0f}\""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("images", nargs="+", help="corpus image ids")
    parser.add_argument("--scale", nargs=2, type=float, metavar=("LOW", "HIGH"), required=True,
                        help="pixel scale range [arcsec/px]")
    parser.add_argument("--cpulimit", type=int, default=150)
    parser.add_argument("--tweak-order", type=int, default=2, metavar="N",
                        help="SIP order of astrometry.net's fit (its default 2); with a solve, the image centre's "
                             "line of sight from that WCS is compared with ours and with the manifest's reference")
    args = parser.parse_args(argv)
    if shutil.which("solve-field") is None:
        print("solve-field not found: apt-get install astrometry.net astrometry-data-tycho2-10-19", file=sys.stderr)
        return 2
    from astropy.io import fits

    from star_tracker.centroid import extract_spots
    from star_tracker.commands.images import read_image
    from star_tracker.commands.solve import centroid_config

    defaults = argparse.Namespace(detection_sigma=4.5, psf_sigma=None, max_spots=150)
    for image in bench.load_corpus(bench.find_corpus(), args.images):
        code, ours, _, _ = bench.run_solve_command(bench.solve_argv(image))
        pixels = read_image(image.path)
        spots = extract_spots(pixels.pixels, centroid_config(pixels.pixels, pixels.description, defaults))
        height, width = pixels.pixels.shape
        with tempfile.TemporaryDirectory() as work:
            xy = Path(work) / "spots.xy.fits"
            fits.BinTableHDU.from_columns([fits.Column(name="X", format="D", array=spots.x + 1.0),  # FITS: 1-based
                                           fits.Column(name="Y", format="D", array=spots.y + 1.0),
                                           fits.Column(name="FLUX", format="D", array=spots.flux)]).writeto(xy)
            run = subprocess.run(["solve-field", "--overwrite", "--no-plots", "--width", str(width), "--height",
                                  str(height), "--scale-units", "arcsecperpix", "--scale-low", str(args.scale[0]),
                                  "--scale-high", str(args.scale[1]), "--sort-column", "FLUX", "--cpulimit",
                                  str(args.cpulimit), "--tweak-order", str(args.tweak_order), "--dir", work, str(xy)],
                                 capture_output=True, text=True)
            wcs_file = Path(work) / "spots.xy.wcs"  # solve-field names its outputs after the input, less .fits
            centre = wcs_centre(wcs_file, width, height) if wcs_file.exists() else None
        best = anet_best(run.stdout + run.stderr)
        if centre is not None:
            print(f"{image.id}: astrometry.net solved (SIP order {args.tweak_order}); image centre "
                  f"{_apart(centre, ours, code)} from ours, "
                  + (f"{_arcsec(centre, image.reference[:, 2]):.0f}\" from the manifest's reference"
                     if image.reference is not None else "no manifest reference"), flush=True)
        mine = (f"ours: RA {ours['ra_deg']:.4f} Dec {ours['dec_deg']:+.4f}, {len(ours['matched'])} stars"
                if code == 0 else "ours: not solved")
        if best is None or best["ra_deg"] is None:
            print(f"{image.id}: {len(spots)} spots; astrometry.net: no match; {mine}")
            continue
        text = (f"{image.id}: {len(spots)} spots; astrometry.net best: RA {best['ra_deg']:.4f} Dec "
                f"{best['dec_deg']:+.4f}, log-odds {best['log_odds']:.1f} ({best['matches']} match, "
                f"{best['conflicts']} conflict; it accepts at 20.7); {mine}")
        if code == 0:
            ra1, dec1, ra2, dec2 = map(math.radians, (best["ra_deg"], best["dec_deg"], ours["ra_deg"], ours["dec_deg"]))
            cos = math.sin(dec1) * math.sin(dec2) + math.cos(dec1) * math.cos(dec2) * math.cos(ra1 - ra2)
            text += f"; apart {math.degrees(math.acos(min(1.0, cos))) * 3600:.0f}\""
        print(text, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
