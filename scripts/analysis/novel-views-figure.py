#!/usr/bin/env python3
"""docs/novel-views-dlf-dagger.png: the test view at one step rendered by the same renderer on
NeuroFluid's, DLF's, DLF†'s and the true particles, by the warm-up's renderer on the true
particles, and NeRF-T's render, beside the truth (BENCHMARKS.md, nineteenth session).

    python3 scripts/analysis/novel-views-figure.py   # needs Pillow (the test bed's venv has it)

Reads the renders the evaluation saves (`eval.render_truth`, `eval.render_dlf`) in
`runs/r17/<scene>-ship-dlf` (the shipped seed-10 run evaluated with DLF†) and
`runs/r17/<scene>-frozen-dlf` (the frozen-renderer probe), and NeRF-T's in
`runs/r12/<scene>-ship/nerf-t`.
"""
from PIL import Image, ImageDraw, ImageFont
font=ImageFont.truetype('/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf',12)
rows=[]
for scene in ['water-dam','honey-drop']:
    base=f'runs/r17/{scene}-ship-dlf/eval/renders/view_5/'
    fz=f'runs/r17/{scene}-frozen-dlf/eval/renders/view_5/'
    nt=f'runs/r12/{scene}-ship/nerf-t/renders/view_5/'
    t=25
    labels=['NeuroFluid','on DLF','on DLF†','on the truth','frozen, on the truth','NeRF-T','truth']
    srcs=[base+f't{t:04}.png', base+f'dlf_particles_t{t:04}.png', base+f'dlf_supervised_particles_t{t:04}.png', base+f'true_particles_t{t:04}.png', fz+f'true_particles_t{t:04}.png', nt+f't{t:04}.png']
    panels=[]
    for p in srcs:
        im=Image.open(p).convert('RGB'); w,h=im.size
        panels.append(im.crop((0,0,w//2,h)) if w>=2*h else im)
    im=Image.open(srcs[0]).convert('RGB'); w,h=im.size
    panels.append(im.crop((w//2,0,w,h)))
    s=2
    panels=[p.resize((p.size[0]*s,p.size[1]*s),Image.LANCZOS) for p in panels]
    pw,ph=panels[0].size
    row=Image.new('RGB',(pw*len(panels),ph+34),'white')
    d=ImageDraw.Draw(row)
    for i,(p,l) in enumerate(zip(panels,labels)):
        row.paste(p,(i*pw,16)); d.text((i*pw+4,1),l,fill=(0,0,0),font=font)
    d.text((4,ph+17),f'{scene}-z, test view, t = {t} (seed 10; the renderer is the grounded one except "frozen": the warm-up\'s)',fill=(90,90,90),font=font)
    rows.append(row)
W=max(r.size[0] for r in rows); H=sum(r.size[1] for r in rows)
out=Image.new('RGB',(W,H),'white'); y=0
for r in rows: out.paste(r,(0,y)); y+=r.size[1]
out.save('docs/novel-views-dlf-dagger.png'); print(out.size)
