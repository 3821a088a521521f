import json, sys
for s in sys.argv[1:]:
    try: rows=[json.loads(l) for l in open(f'docs/capture_check/results/confirm_{s}.jsonl')]
    except FileNotFoundError: continue
    fix=lambda k: k|{'medians_suspect': bool(k['pairs']>=3 and ((k['rmed'] or 0)>1.5 or (k['tmed'] or 0)>1.5)), 'rule4_suspect': bool(k['pairs']>=3 and ((k['rmed'] or 0)>1.5 or (k['tmed'] or 0)>1.5 or k['split']>0))}
    kept=[fix(r['kept'])|{'scene':r['scene'],'subset':r['subset']} for r in rows if 'rot' in r['kept']]
    right=[k for k in kept if k['rot']<1]; far=[k for k in kept if k['rot']>10]; mid=[k for k in kept if 1<=k['rot']<=10]
    print(f"{s}: rows {len(rows)} kept {len(kept)} | right {len(right)} med-flag {sum(k['medians_suspect'] for k in right)} r4-flag {sum(k['rule4_suspect'] for k in right)} max-med {max(max(k['rmed'] or 0,k['tmed'] or 0) for k in right):.2f} | mid {len(mid)} med {sum(k['medians_suspect'] for k in mid)} r4 {sum(k['rule4_suspect'] for k in mid)} | far {len(far)} med {sum(k['medians_suspect'] for k in far)} r4 {sum(k['rule4_suspect'] for k in far)}")
    for k in right:
        if k['rule4_suspect']: print('  RIGHT FLAGGED', k)
    for k in far:
        if not k['rule4_suspect']: print('  FAR MISSED', k['scene'], k['subset'], k['placed'], k['rot'], k['pairs'], k['rmed'], k['tmed'], k['split'])
    g=[fix(r['global']) for r in rows if 'global' in r and 'rot' in r['global']]
    print(f"  global {len(g)}: right {sum(x['rot']<1 for x in g)} | passed(r4) {sum(not x['rule4_suspect'] for x in g)} of which >10 {sum((not x['rule4_suspect']) and x['rot']>10 for x in g)}, 1-10 {sum((not x['rule4_suspect']) and 1<=x['rot']<=10 for x in g)} | passed(med) {sum(not x['medians_suspect'] for x in g)} of which >10 {sum((not x['medians_suspect']) and x['rot']>10 for x in g)}")
