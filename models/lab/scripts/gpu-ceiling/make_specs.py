"""Press lists for the GPU ceiling study (see README.md): the training set
(people 0-6 on the training units, half hand-held, any rotation the
simulator draws), the study's index (people 0-7 on units 0-3, jig) and its
query groups (held-out people on a training unit, on held-out units, and
hand-held)."""
import random, sys

out = sys.argv[1]
per_textile = int(sys.argv[2]) if len(sys.argv) > 2 else 48
textiles = [f"T{i:03d}" for i in range(1, 120)]
units = [0, 1, 2, 3, 6, 7, 8, 9, 10, 11, 12, 13, 14]


def write(name, rows):
    with open(f"{out}/{name}.txt", "w") as f:
        f.write("\n".join(" ".join(map(str, r)) for r in rows) + "\n")


rng = random.Random(7)
train = []
for t in textiles:
    for k in range(per_textile):
        p = rng.randrange(7)
        train.append((t, p, rng.choice(units), 1 if k % 2 == 0 else 0, 70000 + k * 7 + p))
write("tr", train)
write("idx", [(t, p, p % 4, 1, 1000 + p) for t in textiles for p in range(8)])
write("qa", [(t, p, 0, 1, 2000 + p) for t in textiles for p in (8, 11, 14)])
write("qb", [(t, p, u, 1, 2000 + p) for t in textiles for p, u in ((9, 4), (10, 5), (12, 4), (13, 5))])
write("qh", [(t, p, 0, 0, 3000 + p) for t in textiles for p in (8, 11, 14)])
