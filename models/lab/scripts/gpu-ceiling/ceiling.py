"""The GPU ceiling study (README.md): a ResNet-18 trained with cross-entropy
on simulated catalogue-2 presses (frame minus reference, colours whitened per
frame as wspec does), scored per press by cosine 1-NN of its penultimate
features against the study's index, for the held-out groups of the lab's
protocol and the cross-generator set. An experiment, not part of the
product: it needs a GPU, which the product never does.

usage: ceiling.py <dir of dump_presses output> <max steps> <batch> <side: 240|120>
BUDGET (environment): seconds of training; the step count is cut to fit."""
import numpy as np, torch, torch.nn as nn, torch.nn.functional as F, time, sys, os, json
import torchvision
dev='cuda' if torch.cuda.is_available() else 'cpu'
D=sys.argv[1]; STEPS=int(sys.argv[2]); BATCH=int(sys.argv[3]); SIDE=int(sys.argv[4]) if len(sys.argv)>4 else 240
t0=time.time()
S=240
def load(name):
    meta=[l.split() for l in open(f"{D}/{name}.meta.txt")]
    n=len(meta)
    fr=np.fromfile(f"{D}/{name}.frames.u8",dtype=np.uint8).reshape(n,6,S,S,3)
    rf=np.fromfile(f"{D}/{name}.ref.u16",dtype=np.uint16).reshape(n,S,S,3).astype(np.int16)
    lab=np.array([int(m[0][1:])-1 for m in meta])
    k=int(os.environ.get('SMOKE','0'))
    if k: fr,rf,lab=fr[:k],rf[:k],lab[:k]
    return torch.from_numpy(fr).to(dev),torch.from_numpy(rf).to(dev),torch.from_numpy(lab).to(dev)
def prep(fr,rf,pi,fi):
    # diff in DN, channels first, per-frame colour whitening, optional 2x2 average
    x=fr[pi,fi].float()-rf[pi].float()/64.0          # [B,S,S,3]
    x=x.permute(0,3,1,2)
    if SIDE==120: x=F.avg_pool2d(x,2)
    x=x-x.mean((2,3),keepdim=True)
    B=x.shape[0]; v=x.reshape(B,3,-1)
    C=v@v.transpose(1,2)/v.shape[2]
    C=C+torch.eye(3,device=x.device)*(1e-3*C.diagonal(dim1=1,dim2=2).mean(1)[:,None,None]+1e-6)
    e,V=torch.linalg.eigh(C)
    W=V@torch.diag_embed(e.clamp_min(1e-9).rsqrt())@V.transpose(1,2)
    return (W@v).reshape_as(x)
tr=load('tr'); print('loaded train',tr[0].shape,f'{time.time()-t0:.0f}s',flush=True)
sets={k:load(k) for k in ['idx','qa','qb','qh','g2idx','g2qa','g2qh']}
print('loaded sets',f'{time.time()-t0:.0f}s',flush=True)
m=torchvision.models.resnet18(num_classes=119)
m.fc=nn.Identity(); head=nn.Linear(512,119)
m=m.to(dev).to(memory_format=torch.channels_last); head=head.to(dev)
opt=torch.optim.AdamW(list(m.parameters())+list(head.parameters()),lr=2e-3,weight_decay=0.05)
BUDGET=float(os.environ.get('BUDGET','1e9'))  # seconds of training
import math
def set_lr(st,T):
    w=min(1.0,(st+1)/100); lr=2e-3*w*0.5*(1+math.cos(math.pi*min(st,T)/T))
    for g in opt.param_groups: g['lr']=lr
N=tr[0].shape[0]
def embed(s):
    fr,rf,lab=s; out=[]
    m.eval()
    with torch.no_grad(), torch.autocast(dev,dtype=torch.bfloat16,enabled=dev=='cuda'):
        for i in range(0,fr.shape[0],64):
            pi=torch.arange(i,min(i+64,fr.shape[0]),device=dev)
            es=[]
            for f in (3,4,5):
                es.append(F.normalize(m(prep(fr,rf,pi,torch.full_like(pi,f)).contiguous(memory_format=torch.channels_last)).float(),dim=1))
            out.append(torch.stack(es,1))
    m.train()
    return torch.cat(out),lab
def top1(I,il,Q,ql):
    Ie=I.reshape(-1,I.shape[-1]); Il=il.repeat_interleave(I.shape[1])
    q=F.normalize(Q.mean(1),dim=1)
    return (Il[(q@Ie.T).argmax(1)]==ql).float().mean().item()
def evaluate(tag):
    E={k:embed(v) for k,v in sets.items()}
    r={}
    for i,q in [('idx','qa'),('idx','qb'),('idx','qh'),('g2idx','g2qa'),('g2idx','g2qh')]:
        r[q]=round(100*top1(*E[i],*E[q]),1)
    print(tag,json.dumps(r),f'{time.time()-t0:.0f}s',flush=True)
    return r
T=STEPS; t_train=time.time(); st=0
while st<T:
    if st==30:
        per=(time.time()-t_train)/30; T=max(60,min(STEPS,int(BUDGET/per))); print('step time',round(per,4),'steps',T,flush=True)
    set_lr(st,T)
    pi=torch.randint(0,N,(BATCH,),device=dev); fi=torch.randint(0,6,(BATCH,),device=dev)
    x=prep(*tr[:2],pi,fi).contiguous(memory_format=torch.channels_last)
    with torch.autocast(dev,dtype=torch.bfloat16,enabled=dev=='cuda'):
        loss=F.cross_entropy(head(m(x)).float(),tr[2][pi],label_smoothing=0.1)
    opt.zero_grad(set_to_none=True); loss.backward(); opt.step()
    if st%200==0: print(st,round(loss.item(),3),f'{time.time()-t0:.0f}s',flush=True)
    st+=1
res=evaluate('final')
out=os.environ.get('OUT','.')
json.dump(res,open(f'{out}/ceiling.json','w'))
