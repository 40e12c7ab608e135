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
# flexion/extension: whole flexion-to-extension arcs, degrees (in vivo; abstracts, see
# docs/model.md): O-C1 Kaneko et al. 2018 (MRI, 157 volunteers); C2-C3 and C5-C6 Anderst
# et al. 2015 J Biomech (biplane radiography, 29 subjects); C2/3 and C4/5 Wu et al. 2007
# (videofluoroscopy, 56 subjects)
fe = {"o-c1": [("Kaneko 2018", 9.91)], "c2-c3": [("Anderst 2015", 12.7), ("Wu 2007", 13.5)],
      "c4-c5": [("Wu 2007", 22.6)], "c5-c6": [("Anderst 2015", 19.7)]}
print("flexion/extension, whole arcs at the full range (the rule puts every level at its limits)")
print("| level | rule (limits' arc) | in vivo | rule - in vivo |")
for k in reversed(range(8)):
    n = JOINT_NAMES[k]
    rng = lim[k, 0, 1] - lim[k, 0, 0]
    seen = fe.get(n, [])
    vivo = "; ".join(f"{v} ({src})" for src, v in seen) or "-"
    diff = "; ".join(f"{rng - v:+.1f}" for _, v in seen) or "-"
    print(f"| {n} | {rng:.0f} | {vivo} | {diff} |")
print(f"ratios: C2-C3 / C5-C6 in vivo {12.7 / 19.7:.2f} (Anderst), C2/3 / C4/5 {13.5 / 22.6:.2f} (Wu); "
      f"the rule's {(lim[5, 0, 1] - lim[5, 0, 0]) / (lim[2, 0, 1] - lim[2, 0, 0]):.2f} and "
      f"{(lim[5, 0, 1] - lim[5, 0, 0]) / (lim[3, 0, 1] - lim[3, 0, 0]):.2f}")
