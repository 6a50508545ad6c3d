import numpy as np
import pytest

from fpv_station.core import geodesy as g

HOME = (43.0021, -78.7875, 180.0)


def test_ecef_known_points_to_the_millimetre():
    # Equator / prime meridian at h=0 lies at the semi-major axis.
    np.testing.assert_allclose(g.geodetic_to_ecef(0, 0, 0), [6378137.0, 0, 0], atol=1e-3)
    # North pole: the semi-minor axis b = a(1-f).
    b = 6378137.0 * (1 - 1 / 298.257223563)
    np.testing.assert_allclose(g.geodetic_to_ecef(90, 0, 0), [0, 0, b], atol=1e-3)
    # 45 N 90 E at 1000 m, from the closed form with the prime-vertical radius N.
    a, e2 = 6378137.0, 6.69437999014e-3
    lat = np.radians(45)
    n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    expect = [0.0, (n + 1000) * np.cos(lat), (n * (1 - e2) + 1000) * np.sin(lat)]
    np.testing.assert_allclose(g.geodetic_to_ecef(45, 90, 1000), expect, atol=1e-3)


def test_enu_of_point_north_and_east_to_the_centimetre():
    lat0, lon0, alt0 = HOME
    # Radii of curvature at the origin give the degree offsets of 100 m N and 50 m E.
    a, e2 = 6378137.0, 6.69437999014e-3
    phi = np.radians(lat0)
    m = a * (1 - e2) / (1 - e2 * np.sin(phi) ** 2) ** 1.5
    n = a / np.sqrt(1 - e2 * np.sin(phi) ** 2)
    lat = lat0 + np.degrees(100 / (m + alt0))
    lon = lon0 + np.degrees(50 / ((n + alt0) * np.cos(phi)))
    enu = g.geodetic_to_enu(lat, lon, alt0, *HOME)
    np.testing.assert_allclose(enu[:2], [50, 100], atol=0.01)
    assert abs(enu[2]) < 0.01  # earth curvature over 112 m drops ~1 mm


def test_round_trip_vectorized():
    rng = np.random.default_rng(1)
    enu = rng.uniform(-500, 500, size=(1000, 3))
    back = g.geodetic_to_enu(*g.enu_to_geodetic(enu, *HOME).T, *HOME)
    np.testing.assert_allclose(back, enu, atol=1e-6)


def test_alignment_maps_start_reference_line_onto_x():
    lat0, lon0, alt0 = HOME
    # A track that flies 40 m to the north-west, reference further along the same line.
    enu = np.array([[0, 0, 0], [-10, 10, 3], [-20, 20, 3]], float)
    llh = g.enu_to_geodetic(enu, *HOME)
    ref = g.enu_to_geodetic([-30.0, 30.0, 0.0], *HOME)
    aligned = g.track_to_aligned_enu(
        llh[:, 0], llh[:, 1], llh[:, 2], reference_latlon=(ref[0], ref[1])
    )
    np.testing.assert_allclose(aligned[:, 1], 0, atol=1e-3)  # no lateral offset
    np.testing.assert_allclose(aligned[:, 0], [0, np.hypot(10, 10), np.hypot(20, 20)], atol=1e-3)
    np.testing.assert_allclose(aligned[:, 2], [0, 3, 3], atol=1e-3)


def test_alignment_rejects_degenerate_reference():
    with pytest.raises(ValueError, match="coincides"):
        g.heading_alignment_rad((1, 2), (1, 2))
