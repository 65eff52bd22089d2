# Generates host/tests/data/igrf14_worldwide.csv with ppigrf 2.1.0 (IGRF-14): 3,000 points,
# 100 at or next to the poles, 100 on or next to the dateline, the rest uniform on the
# sphere; 0-10 km, 1995-2029. ppigrf gives NaN for north/east exactly at a pole.
import datetime, random, ppigrf
random.seed(22)
pts=[]
for i in range(3000):
    if i < 100: lat = random.choice([90.0,-90.0,89.99,-89.99]); lon = random.uniform(-180,180)
    elif i < 200: lat = random.uniform(-90,90); lon = random.choice([180.0,-180.0,179.999,-179.999])
    else:
        import math
        lat = math.degrees(math.asin(random.uniform(-1,1))); lon = random.uniform(-180,180)
    h = random.uniform(0, 10000)
    y = random.randint(1995, 2029); doy = random.randint(1, 365)
    pts.append((lat, lon, h, datetime.datetime(y,1,1)+datetime.timedelta(days=doy-1)))
print("lat_deg,lon_deg,height_m,date,north_nt,east_nt,down_nt,total_nt")
for lat, lon, h, dt in pts:
    be, bn, bu = ppigrf.igrf(lon, lat, h / 1000.0, dt)
    be, bn, bu = float(be.squeeze()), float(bn.squeeze()), float(bu.squeeze())
    f = (be**2 + bn**2 + bu**2) ** 0.5
    print(f"{lat:.6f},{lon:.6f},{h:.1f},{dt:%Y-%m-%d},{bn:.4f},{be:.4f},{-bu:.4f},{f:.4f}")
