cd /work/wt/model
for L in none ff_t ff_v coulomb; do
  timeout 300 .venv/bin/clutch fit tests/data/golden/bags/table3_seq2_10rpm --law $L -o /tmp/fit_$L.yaml > /tmp/fit_$L.log 2>&1
  timeout 300 .venv/bin/clutch replay tests/data/golden/bags/table3_seq{1,3,4,5}_10rpm tests/data/golden/bags/table3_seq{1,2,3,4,5}_30rpm tests/data/golden/bags/table4_seq{1,2,3,4} --params /tmp/fit_$L.yaml --json > /tmp/replay_$L.json 2>/tmp/replay_$L.err
  .venv/bin/python -c "
import json,sys; r=json.load(open('/tmp/replay_$L.json')); q=[(x['bag'].split('/')[-1], x['rmse_nm']/x['reference_rmse_nm']) for x in r]
print('$L', ' '.join(f'{b}={v:.2f}' for b,v in q), 'mean=%.2f max=%.2f'%(sum(v for _,v in q)/len(q), max(v for _,v in q)))" >> /tmp/ratios.txt 2>&1
done
echo done >> /tmp/ratios.txt
