"""Probe: does a split of the arm's roll between upper arm and forearm, scored on the surface, find the reach_up
adults' true arms (reach_twist_probe.py: their misses are upper-arm rolls made up by elbow twist)?

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/roll_split_probe.py > experiments/fitting/stature/roll_split_probe.txt

For each reach_up adult of the user-scan suite (seeds 0 and 1), ``arteq-fit``'s fit (defaults, ``anny_scan``);
each arm's upper arm rolled about its own axis by th and the forearm then by ph about its own, in 30 degree
steps (144 candidates, nothing refined again). Score: the arm branch's mean distance to the scan plus the
mean distance of the scan points nearest it to the branch (cm, halved). Printed: the fit's score and V2V, the
three best-scoring candidates and the lowest V2V of any candidate.
"""
import sys, numpy as np, torch, roma
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import user_scans as us
from arteq.fit import Fitter
from arteq.body.skeleton import JOINT_NAMES, PARENTS
from scipy.spatial import cKDTree


def main() -> None:
    torch.set_num_threads(1)
    f = Fitter(ckpt="anny_scan", device="cpu", points=5000, anny=False)
    import copy
    body = copy.deepcopy(f.body).double()
    parts = body.part_labels.numpy()
    def branch(j):
        out = {j}; ch = True
        while ch:
            ch = False
            for k, p in enumerate(PARENTS):
                if p in out and k not in out: out.add(k); ch = True
        return sorted(out)
    def axis_rot(axis, deg):
        return roma.rotvec_to_rotmat(torch.as_tensor(axis / np.linalg.norm(axis) * np.radians(deg)))
    for seed in (0, 1):
        for s in us.people_scans(seed):
            if s.group != "adults" or "reach_up" not in s.name: continue
            r = f.fit_points(s.points, name=s.name)
            local = roma.rotvec_to_rotmat(torch.as_tensor(r.pose_aa, dtype=torch.float64))
            betas = torch.as_tensor(r.betas, dtype=torch.float64)[None]
            transl = torch.as_tensor(r.transl_m, dtype=torch.float64)[None]
            base = body(betas=betas, pose=local[None], transl=transl)
            assert np.abs(base.vertices[0].numpy() - r.vertices).max() < 1e-3
            tree = cKDTree(s.points)
            for side in ("left", "right"):
                sh, el, wr = (JOINT_NAMES.index(f"{side}_{n}") for n in ("shoulder", "elbow", "wrist"))
                bv = np.isin(parts, branch(sh))
                G = base.global_rotmats[0]; J = base.joints[0].numpy()
                au = J[el] - J[sh]; af = J[wr] - J[el]
                res = []
                for th in range(-180, 180, 30):
                    for ph in range(-180, 180, 30):
                        Ru = axis_rot(au, th)
                        Gs = Ru @ G[sh]
                        Ge = axis_rot((Ru.numpy() @ af), ph) @ Ru @ G[el]
                        L = local.clone()
                        L[sh] = G[PARENTS[sh]].T @ Gs
                        L[el] = Gs.T @ Ge
                        out = body(betas=betas, pose=L[None], transl=transl)
                        v = out.vertices[0].numpy()
                        d1 = tree.query(v[bv])[0]
                        near = cKDTree(v).query(s.points)[1]
                        mine = bv[near]
                        d2 = cKDTree(v[bv]).query(s.points[mine])[0]
                        score = (np.mean(d1) + np.mean(d2)) * 50
                        v2v = np.linalg.norm(v - s.vertices, axis=1).mean() * 100
                        res.append((score, th, ph, v2v))
                res.sort()
                z = [x for x in res if x[1] == 0 and x[2] == 0][0]
                print(seed, s.name[:30], side, "fit: score %.3f V2V %.2f" % (z[0], z[3]), "| best:", " ".join("(%.3f th%d ph%d V2V %.2f)" % x for x in res[:3]), "| min V2V %.2f" % min(x[3] for x in res), flush=True)


if __name__ == "__main__":
    main()
