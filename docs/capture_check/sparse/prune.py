"""Oracle test: map ring12's match database with only pairs up to K steps apart (truth order) vs all pairs."""
import json, shutil, sys
from pathlib import Path
import numpy as np, pycolmap
from blender_mrvm.capture import align, sfm
from blender_mrvm.geometry import cameras as C
scenes, work = Path(sys.argv[1]), Path(sys.argv[2]); K = int(sys.argv[3]); drop_planar = len(sys.argv) > 4
res = []
for sd in sorted(work.glob('scene*')):
    tj = json.loads((scenes / sd.name / 'truth.json').read_text()); truth = {v['name']: np.array(v['c2w_opencv']) for v in tj['views']}
    src = sd / 'ring12/base/cap/colmap/database.match.db'
    if not src.is_file(): src = sd / 'ring12/base/cap/colmap/database.db'
    d = sd / 'ring12/prune'; shutil.rmtree(d, ignore_errors=True); d.mkdir(parents=True)
    db_path = d / 'db.db'; shutil.copy(src, db_path)
    db = pycolmap.Database.open(str(db_path))
    names = {im.image_id: im.name for im in db.read_all_images()}; order = sorted(names.values())
    pids, geoms = db.read_two_view_geometries(); dropped = 0
    for pid, g in zip(pids, geoms):
        a, b = sfm._pair_to_ids(pid); k = (order.index(names[b]) - order.index(names[a])) % 12; k = min(k, 12 - k)
        planar = str(g.config).endswith('6') or 'PLANAR' in str(g.config)
        if k > K or (drop_planar and planar and k > 1):
            db.delete_two_view_geometry(a, b); dropped += 1
    db.close()
    # images: copy pngs
    imgs = d / 'images'; imgs.mkdir()
    for n in order: shutil.copy(scenes / sd.name / 'images' / n, imgs / n)
    o = pycolmap.IncrementalPipelineOptions(); o.num_threads = 1; o.random_seed = 0; o.min_model_size = 3
    sp = d / 'sparse'; sp.mkdir()
    recs = pycolmap.incremental_mapping(db_path, imgs, sp, o)
    r = max(recs.values(), key=lambda r: r.num_reg_images()) if recs else None
    row = {'scene': sd.name, 'K': K, 'dropped': dropped, 'placed': r.num_reg_images() if r else 0}
    if r and r.num_reg_images() >= 3:
        ids = list(r.reg_image_ids())
        e = align.pose_errors([C.c2w_opencv_from_w2c(r.images[i].cam_from_world().matrix()) for i in ids], [truth[r.images[i].name] for i in ids])
        row['rot_med'] = round(e.median_rotation_deg, 2)
    print(json.dumps(row), flush=True); res.append(row)
ok = sum(1 for r in res if r['placed'] == 12 and r.get('rot_med', 99) < 1)
print('whole and right:', ok, 'of', len(res), '; placed>=6 right:', sum(1 for r in res if r['placed'] >= 6 and r.get('rot_med', 99) < 1))
