"""Per-image products of ``adfusion solve``: JSON record, FITS WCS, correspondence table.

Like astrometry.net's ``solve-field`` outputs, beside a JSON record of the solution:

* ``<stem>.wcs`` — a FITS file whose primary header holds the TAN(-SIP) WCS
  (:func:`adfusion.starid.camera.wcs.wcs_header`), no data;
* ``<stem>.corr`` — a FITS binary table, one row per matched star: the detection's pixel
  (``FIELD_X``/``FIELD_Y``, 0-based pixel centres: ``PIXORIGN = 0`` in the header; add 1
  for FITS/solve-field pixels) and its RA/Dec through our solution, the catalogue star's
  id, RA/Dec at the epoch, magnitude and predicted pixel, and the residual.

Example:
    >>> from adfusion.app.products import summary_table
    >>> print(summary_table([{"image": "a.tiff", "ok": False, "reason": "too few stars",
    ...                       "detections": 2}]))
    image   ok  det  matched  RA°  Dec°  roll°  FOV°  RMS″  p_false  ms
    a.tiff  no    2        -    -     -      -     -     -        -   -
    1 image(s): 0 solved, 1 not (a.tiff: too few stars)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["match_rows", "summary_table", "write_corr", "write_wcs"]


def match_rows(sol, catalog, xy) -> list[dict]:
    """One dict per matched star: detection index and pixel, catalogue id, RA/Dec (deg)
    and magnitude at the catalogue's epoch, predicted pixel, residual (arcsec)."""
    from adfusion.maths import rotations as rot

    if not sol.ok or not sol.matches:
        return []
    xy = np.asarray(xy, np.float64)
    ids = np.asarray(catalog.ids)
    order = np.argsort(ids, kind="stable")
    det = np.array([d for d, _ in sol.matches], np.int64)
    cid = np.array([i for _, i in sol.matches], np.int64)
    k = order[np.searchsorted(ids, cid, sorter=order)]
    v = np.asarray(catalog.vectors)[k]
    ra, dec = rot.vector_to_radec(v)
    pred = sol.camera.vectors_to_pixels(rot.rotate(sol.q_cam_icrs, v))
    mag = np.asarray(catalog.mag)[k]
    return [{"detection": int(d), "x": round(float(xy[d, 0]), 3),
             "y": round(float(xy[d, 1]), 3), "id": int(i),
             "ra_deg": round(float(np.degrees(a)) % 360.0, 7),
             "dec_deg": round(float(np.degrees(b)), 7), "mag": round(float(m), 3),
             "x_pred": round(float(p[0]), 3), "y_pred": round(float(p[1]), 3),
             "residual_arcsec": round(float(np.degrees(r) * 3600), 3)}
            for d, i, a, b, m, p, r in zip(det, cid, ra, dec, mag, pred, sol.residuals_rad,
                                           strict=True)]


def write_wcs(path: str | Path, sol, epoch: float | None = None) -> Path:
    """Write the solution's WCS as a header-only FITS file (solve-field's ``.wcs``)."""
    from astropy.io import fits

    from adfusion.starid.camera.wcs import wcs_header

    h = wcs_header(sol.camera, sol.q_cam_icrs)
    if epoch is not None:
        h["EPOCH"] = (float(epoch), "catalogue epoch, Julian year")
    h["PIXORIGN"] = (1, "pixels counted from 1 (adfusion: 0)")
    p = Path(path)
    fits.PrimaryHDU(header=h).writeto(p, overwrite=True)
    return p


def write_corr(path: str | Path, sol, rows: list[dict]) -> Path:
    """Write the matched stars (:func:`match_rows`) as a FITS table (solve-field's
    ``.corr``, with our column names and 0-based pixels)."""
    from astropy.io import fits

    from adfusion.maths import rotations as rot

    xy = np.array([[r["x"], r["y"]] for r in rows], np.float64).reshape(-1, 2)
    if len(xy):
        f_ra, f_dec = rot.vector_to_radec(rot.rotate(rot.inverse(sol.q_cam_icrs),
                                                     sol.camera.pixels_to_vectors(xy)))
        f_ra, f_dec = np.degrees(f_ra) % 360.0, np.degrees(f_dec)
    else:
        f_ra = f_dec = np.zeros(0)

    def col(name: str, fmt: str, values, unit: str | None = None) -> fits.Column:
        return fits.Column(name=name, format=fmt, array=np.asarray(values), unit=unit)

    cols = [
        col("FIELD_ID", "J", [r["detection"] for r in rows]),
        col("FIELD_X", "D", xy[:, 0], "pix"), col("FIELD_Y", "D", xy[:, 1], "pix"),
        col("FIELD_RA", "D", f_ra, "deg"), col("FIELD_DEC", "D", f_dec, "deg"),
        col("INDEX_ID", "K", [r["id"] for r in rows]),
        col("INDEX_RA", "D", [r["ra_deg"] for r in rows], "deg"),
        col("INDEX_DEC", "D", [r["dec_deg"] for r in rows], "deg"),
        col("INDEX_X", "D", [r["x_pred"] for r in rows], "pix"),
        col("INDEX_Y", "D", [r["y_pred"] for r in rows], "pix"),
        col("MAG", "D", [r["mag"] for r in rows], "mag"),
        col("RESIDUAL", "D", [r["residual_arcsec"] for r in rows], "arcsec"),
    ]
    hdu = fits.BinTableHDU.from_columns(cols)
    hdu.header["PIXORIGN"] = (0, "pixels counted from 0 (FITS: 1)")
    p = Path(path)
    fits.HDUList([fits.PrimaryHDU(), hdu]).writeto(p, overwrite=True)
    return p


def summary_table(records: list[dict]) -> str:
    """A plain-text table of solve records (the CLI's batch summary), then a count line."""
    head = ["image", "ok", "det", "matched", "RA°", "Dec°", "roll°", "FOV°", "RMS″",
            "p_false", "ms"]
    rows = []
    for r in records:
        if r.get("ok"):
            rows.append([r["image"], "yes", str(r.get("detections", "-")),
                         str(len(r["matches"])), f"{r['ra_deg']:.4f}", f"{r['dec_deg']:+.4f}",
                         f"{r['roll_deg']:.3f}", f"{r['fov_x_deg']:.3f}",
                         f"{r['rms_residual_arcsec']:.1f}", f"{r['p_false']:.0e}",
                         f"{r['time_ms']:.1f}"])
        else:
            rows.append([r["image"], "no", str(r.get("detections", "-"))] + ["-"] * 8)
    widths = [max(len(h), *(len(row[k]) for row in rows)) for k, h in enumerate(head)]

    def fmt(cells: list[str]) -> str:
        return "  ".join(c.ljust(w) if k == 0 else c.rjust(w)
                         for k, (c, w) in enumerate(zip(cells, widths, strict=True))).rstrip()

    lines = [fmt(head)] + [fmt(row) for row in rows]
    bad = [r for r in records if not r.get("ok")]
    tail = f"{len(records)} image(s): {len(records) - len(bad)} solved, {len(bad)} not"
    if bad:
        tail += " (" + "; ".join(f"{r['image']}: {r.get('reason', '')}" for r in bad[:5])
        tail += "; …)" if len(bad) > 5 else ")"
    return "\n".join([*lines, tail])
