# Generates host/tests/data/igrf14_reference.csv with ppigrf 2.1.0 (IGRF-14).
import datetime, ppigrf
pts = [  # lat_deg, lon_deg, height_m (ellipsoid), date
    (45.3147665, -75.6633086, 223.5, "2020-06-29"),   # SGL flight 1003 area (Ottawa)
    (45.3, -75.7, 3000.0, "2020-06-19"),
    (0.0, 0.0, 0.0, "2025-01-01"),
    (-33.9, 18.4, 1500.0, "2024-03-15"),    # South Atlantic anomaly edge
    (78.2, 15.6, 500.0, "2026-07-01"),      # Svalbard, SV extrapolation
    (-77.8, 166.7, 100.0, "2027-12-31"),    # McMurdo
    (64.1, -21.9, 2000.0, "2015-05-05"),
    (35.7, 139.7, 300.0, "2010-10-10"),
    (-23.5, -46.6, 800.0, "2005-02-28"),
    (51.5, -0.1, 150.0, "2000-01-01"),
    (19.4, -99.1, 4000.0, "2029-12-31"),
    (-45.0, 170.0, 10000.0, "2021-08-08"),
    (89.9, 0.0, 1000.0, "2022-01-01"),
    (60.0, 100.0, 300.0, "1995-07-01"),
]
print("# IGRF-14 reference values from ppigrf 2.1.0 (pip: ppigrf), ppigrf.igrf(lon, lat, h_km, date)")
print("lat_deg,lon_deg,height_m,date,north_nt,east_nt,down_nt,total_nt")
for lat, lon, h, d in pts:
    dt = datetime.datetime.strptime(d, "%Y-%m-%d")
    be, bn, bu = ppigrf.igrf(lon, lat, h / 1000.0, dt)
    be, bn, bu = float(be.squeeze()), float(bn.squeeze()), float(bu.squeeze())
    f = (be**2 + bn**2 + bu**2) ** 0.5
    print(f"{lat},{lon},{h},{d},{bn:.3f},{be:.3f},{-bu:.3f},{f:.3f}")
