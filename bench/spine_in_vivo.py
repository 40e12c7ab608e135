"""The spine rule against in-vivo data (issue 60; prints the tables of docs/model.md, "The
spine against in-vivo data"): per-level angles of ``distribute_head_rotation`` (previous,
range-proportional, and current) at the literature's full range, and the joints' limits.

    PYTHONPATH=$PWD python bench/spine_in_vivo.py

Sources are cited beside ``HEAD_SHARE_DEG`` in ``hack_render/geometry/anatomy.py``.
"""
from hack_render.geometry.anatomy import JOINT_NAMES, head_share_deg, limits_deg

lim = limits_deg()
ax = {"o-c1": 1.7, "c1-c2": 36.2, "c2-c3": 2.2, "c3-c4": 4.5, "c4-c5": 4.6, "c5-c6": 4.0, "c6-c7": 1.6, "c7-t1": 1.5}
tot = sum(ax.values())
new = head_share_deg([0, tot, 0])[:, 1]
old = tot * lim[:, 1, 1] / lim[:, 1, 1].sum()
print(f"axial, head angle {tot:.1f} (sum of the measured levels)")
print("| level | in vivo | previous rule | new rule | previous - in vivo | new - in vivo | limit (rule at 77) | limit - in vivo |")
for k in reversed(range(8)):
    n = JOINT_NAMES[k]
    print(f"| {n} | {ax[n]:.1f} | {old[k]:.1f} | {new[k]:.1f} | {old[k]-ax[n]:+.1f} | {new[k]-ax[n]:+.1f} | {lim[k,1,1]:.0f} | {lim[k,1,1]-ax[n]:+.1f} |")
lat = {"c2-c3": 7.66, "c3-c4": 8.37, "c4-c5": 8.91, "c5-c6": 7.19, "c6-c7": 6.31}
ts = sum(lat.values())
idx = [JOINT_NAMES.index(n) for n in lat]
limz = lim[idx, 2, 1]
print(f"lateral (C2-C7 only), the C2-C7 sum {ts:.2f} shared by the rule among those levels")
print("| level | in vivo | share in vivo | rule share | rule at same C2-C7 sum | diff | limit | limit - in vivo |")
for n, k, l in zip(lat, idx, limz):
    r = ts * l / limz.sum()
    print(f"| {n} | {lat[n]:.2f} | {lat[n]/ts:.3f} | {l/limz.sum():.3f} | {r:.2f} | {r-lat[n]:+.2f} | {l:.0f} | {l-lat[n]:+.2f} |")
fe = {"c2-c3": 13.5, "c4-c5": 22.6}
print("| level | in vivo (F+E) | limit F+E (rule at full range) | diff |")
for n, deg in fe.items():
    k = JOINT_NAMES.index(n)
    rng = lim[k, 0, 1] - lim[k, 0, 0]
    print(f"| {n} | {deg} | {rng:.0f} | {rng - deg:+.1f} |")
print("ratio in vivo", 13.5/22.6, "rule", 10/20)
