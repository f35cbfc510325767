"""Evidence for issue 28 item 4 (docs/diagnose.md, real data): Welch spectra of the raw MIMU4444 IMU axes over the
quietest 25 s of each experiment's first half -- per-band shape of the single sensors' PSD, N x PSD(mean)/PSD(single),
the strongest narrow line -- then, per axis, the pairwise coherence at that line against the background's and each
sensor's line strength. Usage: python3 tools/mimu_line_probe.py (data in ../shared/data/mimu4444)."""
import numpy as np, sys
from scipy.signal import welch, csd
import os
D=os.environ.get('MIMU4444_DIR', os.path.join(os.path.dirname(__file__), '../../shared/data/mimu4444'))+'/'
def load(e):
    b=open(D+f'exp_{e}/data.bin','rb').read()[4:]
    n=len(b)//106
    a=np.frombuffer(b[:n*106],dtype=np.uint8).reshape(n,106)
    assert (a[:,0]==0xAA).all()
    v=a[:,8:104].copy().view('>i2').reshape(n,8,6).astype(float)
    return v  # acc xyz, gyro xyz raw counts
for e in range(1,7):
    v=load(e); fs=62.5
    g=v[:,:,3:]/16.4
    # find quietest 25 s window via rolling gyro diff energy
    w=int(25*fs)
    mov=np.abs(np.diff(g.mean(1),axis=0)).sum(1)
    c=np.convolve(mov,np.ones(w),'valid')
    # restrict to first half (static phase)
    k=np.argmin(c[:len(c)//2])
    seg=v[k:k+w]
    print(f'exp_{e}: quiet window at {k/fs:.1f} s')
    for name,idx,scale in [('gyro',3,16.4),('acc',0,2048.0)]:
        for ax in range(3):
            x=seg[:,:,idx+ax]/scale
            x=x-x.mean(0)
            f,P=welch(x,fs=fs,nperseg=256,axis=0)   # per sensor
            Pm=P.mean(1)
            fm,Pc=welch(x.mean(1),fs=fs,nperseg=256)
            bands=[(0.5,1),(1,2),(2,4),(4,8),(8,16),(16,24),(24,31.3)]
            bl=lambda p,lo,hi: p[(f>=lo)&(f<hi)].mean()
            ref=bl(Pm,2,4)
            shape=[round(bl(Pm,lo,hi)/ref,2) for lo,hi in bands]
            ratio=[round(bl(Pc,lo,hi)*8/bl(Pm,lo,hi),2) for lo,hi in bands]
            # line search in cluster mean & singles
            def line(p):
                best=(0,0)
                for i in range(3,len(p)-1):
                    nb=np.r_[p[max(0,i-12):max(0,i-2)],p[i+3:i+13]]
                    r=p[i]/np.median(nb)
                    if r>best[0]: best=(r,f[i])
                return best
            lc=line(Pc); ls=line(Pm)
            q=np.unique(np.round(np.diff(np.sort(np.unique(seg[:,:,idx+ax])))))[:3]
            print(f'  {name}{"xyz"[ax]}: sd/LSB {x.std(0).mean()*scale:.2f}  PSD(2-4Hz) {np.sqrt(ref):.2e}/rtHz shape {shape} N*Pmean/Psingle {ratio} line mean {lc[1]:.2f}Hz x{lc[0]:.1f} singles {ls[1]:.2f}Hz x{ls[0]:.1f}')

# Coherence at the line

for e in [1,2,3,4,6]:
    v=load(e); fs=62.5; w=int(25*fs)
    g=v[:,:,3:]/16.4
    mov=np.abs(np.diff(g.mean(1),axis=0)).sum(1)
    c=np.convolve(mov,np.ones(w),'valid'); k=np.argmin(c[:len(c)//2]); seg=v[k:k+w]
    out=[]
    for name,idx,scale in [('g',3,16.4),('a',0,2048.0)]:
        for ax in range(3):
            x=seg[:,:,idx+ax]/scale; x=x-x.mean(0)
            f,P=welch(x,fs=fs,nperseg=256,axis=0)
            Pm=P.mean(1)
            i=np.argmax([Pm[j]/np.median(np.r_[Pm[max(0,j-12):max(0,j-2)],Pm[j+3:j+13]]) for j in range(3,len(Pm)-1)])+3
            # mean pairwise |coherency| at line bin and at background bins
            cohs=[];cb=[]
            for a in range(8):
                for b in range(a+1,8):
                    _,Cab=csd(x[:,a],x[:,b],fs=fs,nperseg=256)
                    cohs.append(np.abs(Cab[i])/np.sqrt(P[i,a]*P[i,b]))
                    cb.append(np.mean(np.abs(Cab[20:100])/np.sqrt(P[20:100,a]*P[20:100,b])))
            # per-sensor line strength
            strength=[P[i,s]/np.median(P[max(0,i-12):i+13,s]) for s in range(8)]
            out.append(f'{name}{"xyz"[ax]} {f[i]:.2f}Hz coh {np.mean(cohs):.2f} (bg {np.mean(cb):.2f}) per-sensor x{np.round(strength,0)}')
    print(f'exp_{e}:'); [print('  ',o) for o in out]
