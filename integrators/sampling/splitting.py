r"""Efficiency-aware Russian roulette and splitting (EARS) with real path replication.

**The decision.**  At every vertex x of a path the emission found there and the light samples
taken there (:meth:`VertexEstimator.direct`, MIS-weighted) are counted once, for the lane that
reached x.  The rest, the light reflected at x through the BSDF sample, L_r(x), is estimated by
n(x) independent copies of the continuation (a BSDF sample, its ray, the emission it finds, and
everything behind it).  n < 1 is Russian roulette (one copy with probability n, weighted
1/n), n > 1 splitting into m = floor(n) or ceil(n) copies by stochastic rounding (floor(n + u),
u uniform), each weighted 1/m (:func:`split_weight`), so the estimate is unbiased for *any*
n > 0 chosen before the rounding (tested with random n in [0.1, 8] at every vertex).
Roulette never drops a vertex's direct light, only what lies behind it.  One exception: where
the first hit splits (n >= 1), each of its copies takes light samples of its own there, weighted
1/m like the rest of the copy, as in the authors' implementation and ``nee_path``'s ``split``:
where the light samples carry the noise (direct light) the copies then average it too.  (Taken
once, the four copies of ``veach_mis``'s first hits lowered ``nee_path``'s relMSE 1.47x against
``split=4``'s 3.62x, in the same time: ``benchmarks/results/ears_unit_283a320``.  Dropping the
light samples with the continuation where n < 1 as well, as the authors do, traced 1.3-1.4x
the rays per camera sample in the dark scene with a bright light, 10-20 % slower at the same
error: its regions' second moments, the light samples in, allowed less roulette.)  The
statistics are the continuation's alone, at every vertex.

The efficiency-optimal n (Rath, Grittmann, Herholz, Weier, Slusallek 2022, "EARS:
Efficiency-Aware Russian Roulette and Splitting"; Vorba & Krivanek 2016, ADRRS): the work
minimises (sum over pixels of the relative variance) x (total cost).  One copy of the
continuation from x adds w^2 a(x) / n to the relative variance of its pixel, w = lum(beta) /
sqrt(I_p^2 + 0.01) the path's throughput relative to its pixel's value I_p (the relMSE's
denominator), and n c(x) to the cost, c(x) the cost of one copy.  The derivative of V C vanishes
at

    n(x) = w sqrt(a(x) C / (V c(x)))

with V the image's relative variance per camera sample, C its cost per camera sample (rays, a
shadow ray counting ``SHADOW_COST``, a camera sample ``CAMERA_COST`` more), a(x) the second
moment E[L_r^2] where n < 1 (roulette pays the whole second moment; raised by ``RR_MARGIN``,
since a region's second moment is estimated from few heavy-tailed samples and reads low more
often than high) and the variance Var[L_r] where n > 1 (splitting averages only the variance).
n is clamped to [``rr_min``, ``split_max``].  The rule is first-order (V and C include the
vertex's own share, w^2 a / n and n c); iterated over the passes, its fixed point is the exact
optimum n^2 = w^2 a C_o / (V_o c), C_o and V_o the cost and variance of everything else, which
is large where a vertex carries most of its pixel's variance (the first hit of a room lit
indirectly): ``split_max`` bounds it there (4 by default).

**What is learned, and where.**  Per region of two
:class:`~integrators.sampling.learning.RegionGrid` (position and normal octant, a fine one and a
coarse one, the coarse one's factors used where the fine cell has no copies): sums of L_r, L_r^2,
the cost of a copy and the count of copies, from the copies made in the first ``LEARN_DEPTH``
bounces.  A cell's moments are shrunk towards its parent's (a coarse cell's towards the whole
scene's, a fine cell's towards its coarse cell's) with the weight of ``PRIOR_VISITS`` copies, (sum
+ PRIOR_VISITS x parent) / (count + PRIOR_VISITS) (:meth:`EARS.moments`): where the light a vertex
reflects comes from rare paths (light through glass: next-event estimation blocked, every
contribution a rare BSDF-sampled path), a cell that has seen none of them reads a second moment of
zero, and its factor would be ``rr_min`` at every vertex, roulette compounding to weights of 10^k;
shrunk, it keeps the part of the scene's second moment its few copies cannot rule out, and a cell
of many copies its own.  Every such copy has a *record*; each lane keeps, per record of its
ancestors, what it has added since that record was made (registers, no memory traffic per bounce),
and hands it to the records when it ends or splits (the copies start from zero), so when a batch is
finished each record holds its copy's beta_copy L_r and cost.  In the one-kernel passes (below) the
records are registers of the lane itself (:func:`records_start`, :func:`records_add`), scattered to
the grids when the path ends. Per pixel: the running mean of the pixel estimate (I_p; a filtered
value would spread a light's value over its neighbours, whose variance then looks small) and, from
the last pass, its second moment and cost.  Between passes (:meth:`EARS.learn`) each region gets
its two factors sqrt(M C / (V c)) and sqrt(Var C / (V c)); statistics then decay by ``DECAY`` so
that what is learned follows the changing policy.  Until the scene has ``MIN_VISITS`` copies, and
in the first pass (the first part of the first render call, :meth:`EARS.part`: the rest of that
call is rendered in the parts after it, learned, so these samples, the noisiest, are a small
share of the image), a vertex has n = 1 and its copy applies the classic throughput rule after
its BSDF sample (from ``rr_depth`` on, survival min(max(beta) eta^2, 0.95) with the sample's
weight in beta), as Mitsuba's ``path`` does: applied before the sample, the rule lags one
bounce behind and traces a fifth more rays (4.5 against 5.5 continuations per camera sample in
the indirect room).  The learned state lives on the integrator per scene, across the passes
of ``render --spp`` or ``--time``.  Learning stops once the cells hold enough copies
(``SETTLED_COPIES`` in the cell of the median copy, :func:`median_copy_cell`, after
``SETTLED_PASSES`` learned passes in the same mode): the later passes keep the factors and
record nothing (``EARS.settled``, in the run record), which takes the records' cost out of most
of a long render (indirect room, 96 px, 512 spp in
doubling passes: 1.32x -> 1.42x ``nee_path``'s efficiency, before the first call's parts).  The
count is taken where the copies are, not over the cells: where the learned roulette ends most
copies early (the dark scene with a bright light) thousands of cells are each visited by a few
copies: after the four calls of a 512-spp render (32 to 256 spp) the median visited cell held
10-52 copies and learning never stopped, while the cell of the median copy held 233-1993; the
records cost 18 % of a pass there (82 ms against 70 ms frozen, 96 px, 64 spp), 5-7 % in the
room, the mesh and the glossy scene.  A film of another size, or a sensor moved (another
pose or crop: :func:`~integrators.sampling.learning.sensor_view`), starts again from a classic
pass: the pixels' values the factors are relative to are another view's.
The shrinkage replaced two earlier guards against second moments read low: the larger of the
fine and the coarse cell's roulette factor, and a ``MIN_VISITS`` per cell (below it the
throughput rule).  With them,
``glass_shade`` at 96 px was 0.12/0.14/0.71x ``nee_path``'s efficiency at 32/128/512 spp (relMSE
10-22 against 2.0 at 32 spp: the young table's roulette at ``rr_min``) and the indirect room
1.01/1.24/1.28x; with the shrinkage (and :meth:`EARS.learn` on the cells with copies only, 1.5-3 ms
a pass instead of 5) 0.72/0.71/0.76x and 1.28/1.30/1.34x (``benchmarks.ears``, 4 repeats, the same
seeds).

**Modes and the policy.**  A pass runs in one of ``MODES``: ``classic`` while nothing is
learned (the throughput rule, records kept), ``roulette`` (the learned n clamped to one:
survival n where n < 1, no copies), ``split`` (the learned n, splitting at the first
``split_depth`` vertices) and ``plain`` (the throughput rule in the integrator's own kernel,
once a roulette or, under ``auto``, a split pass estimated that learning does not pay; below).
Where the throughput rule ends no path (``max_depth`` at most ``rr_depth``; policies ``never``
and ``auto``) a render starts with a ``bound`` part instead: the plain kernel, its paths' costs
counted (:class:`CostCounter`), which bounds what any roulette could gain by the cost it could
save (:meth:`EARS.bound_gain`): where that is too little the render goes plain without a
learning pass (``veach_mis``, ``small_light``, ``many_lights``, ``sharp_glossy`` at 96 px:
bounds 1.30-1.34; until 2026-12-07 the classic pass measured the bound, its megakernel and
records 14 ms of ``many_lights``'s first 2-spp call of 71 ms, ``nee_path``'s 57 ms).
The classic, roulette and split passes
run every path of a batch in one kernel
(:meth:`Wavefront.roulette_kernel`, Mitsuba's megakernel: the light samples' BSDF sample is
reused for the continuation, rays are counted per lane) when only the first hit may split (the
default ``split_depth`` 1); deeper splitting replicates lanes (below).  ``split_policy``
(``POLICIES``) chooses: ``auto`` (the default, below), ``never`` (roulette only), ``always``,
or ``measured``
(after the classic pass one roulette and one split pass, then the mode of higher measured
efficiency, 1 / (the pass's relative variance against the current pixel means x its seconds
per camera sample, less Dr.Jit's compilation: :func:`pass_clock`), renewed by every learning
pass it runs; when ``classic`` still competed, one early pass's heavy-tailed variance made it the
choice in the indirect room; it now runs only while nothing is learned).  Measured side by side
(96 px, 256 spp in doubling passes, 4 repeats, efficiency relative to ``nee_path
rr=throughput``; never / always / measured): indirect room 1.33 / 1.30 / 1.15, ajar door
0.83 / 1.02 / 0.95, lamp in a glass shade 0.73 / 0.51 / 0.66, ``specular_box`` 0.76 / 0.74 /
0.76: the measured policy pays for its two trial passes and picks between modes whose
difference one pass measures poorly.  The splitting factor scaled by 0.5 or 0.25 (the
roulette factor as is) did not give a policy better everywhere either (always, scale 1 / 0.5 /
0.25: indirect room 1.34 / 1.32 / 1.36, glossy 0.99 / 1.03 / 1.04, ajar door 1.04 / 0.88 /
0.87, glass shade 0.50 / 0.56 / 0.66, roulette only 1.38, 1.04, 0.85, 0.74).

**Policy ``auto``: the roulette estimated on a split pass's paths.**  After the first
roulette pass (which estimates the throughput rule, below) a split pass runs where the
roulette gained ``SPLIT_TRY`` or more over the rule, and every learning split pass estimates,
on its own paths, what a roulette pass with the same table would have cost and how noisy it
would have been, with the same estimator as the rule's below.  Each lane's first copy is a
roulette path but for two things: the first hit's weight 1/n where n > 1 (the roulette's
survival there is one, the copy's weight 1/n: its contributions are counted n times), and
behind it a throughput n times smaller, so that the deeper vertices survive with the learned
factor at the copy's throughput where the roulette would use it at n times that (the survival
ratios along the copy, as for the rule).  The other copies are left out.  The ratio of the
two efficiencies in the cost model's units (``split_gain``, in the run record) decides: the
render splits while it is at least ``SPLIT_COST`` (a split pass's time per unit of work is
1.02-1.26x a roulette pass's: its lanes wait for their packet's most copies), else goes on with
roulette only, and plain where neither the roulette (``gain``) nor the splitting (``gain``
``split_gain`` / ``SPLIT_COST``) is worth ``KERNEL_COST``.  Checked against roulette passes
with the same table (48 px, 128-spp passes after learning; estimated / measured): indirect
room relative variance 3.264 / 3.26 per camera sample, cost 13.024 / 13.027, splitting's gain
1.268 / 1.267; heavy mesh 0.976 / 0.976 (roulette kept), ajar door 1.56 / 1.55, glossy scene
1.22 / 1.22, the dark scene 1.00 (it hardly splits).  A change of mode starts the count of
learned passes before settling again (the statistics recorded under the other policy are not
this one's).  Side by side (96 px, 3 repeats, efficiency relative to ``nee_path``, auto /
never / always, 32/128/512 spp): indirect room 1.20/1.48/1.45, 1.24/1.40/1.48,
1.24/1.56/1.56; ajar door 0.95/1.07/0.98, 0.82/0.94/0.96, 0.99/1.14/1.14; glossy
0.96/1.01/0.96, 1.00/0.93/0.98, 1.01/1.10/1.00; heavy mesh 1.23/1.29/1.28, 1.17/1.28/1.30,
1.03/1.12/1.14.  Splitting pays little over the learned roulette here (1.05-1.15x where it
pays at all, as the estimates say), and the trial pass and the settling before the
splitting's statistics have converged (a split table that learned from roulette passes splits
less: the last pass of a 512-spp render 0.93x ``always``'s efficiency) take most of it.

**The plain fallback: the throughput rule estimated on the learned paths.**  Where the learned
roulette hardly differs from the throughput rule (direct light and short paths: Veach's MIS
scene, where it traces the continuations the rule traces) or gains less than its kernel costs
(the records, the factors' lookups and the pixel statistics: ``KERNEL_COST``, 1.3x the plain
kernel's time per unit of work), learning loses.  So every roulette pass of the ``never``
and ``auto`` policies also estimates, on its own paths, what the throughput rule would have
cost and how noisy it would have been, and :meth:`EARS.compare` takes the ratio of the
efficiencies.  Below ``KERNEL_COST`` (under ``auto`` where splitting, when tried, does not pay
either; above) the rest of the render runs ``plain``: the integrator's own kernel (Mitsuba's
megakernel, ``nee_path`` with the throughput rule, no records), for good.  The estimate is
exact in expectation, not a first-order model.  Along a path let q_a be the learned survival
at vertex a and r_a the rule's (applied to the continuation's BSDF sample and to the
*classic* throughput, beta Q / P), P_v = prod_{a<v} 1/q_a and Q_v = prod_{a<v} 1/r_a over the
decisions before vertex v, and c_v the luminance a path adds at v without roulette weights (the
pass adds P_v c_v).  The learned pass reaches v with probability 1/P_v and the rule with
1/Q_v, so the rule's expected cost is E[sum_v k_v P_v / Q_v] (k_v the rays traced to and at v).
Its estimate of a camera sample is X = sum_v B_v c_v with B_v = prod_{a<v} s_a / r_a
(s_a the survival indicators), and E[B_u B_v | path] = Q_u for u <= v (the shared decisions
give E[s^2/r^2] = 1/r, the others 1), so its second moment is E[sum_v c_v P_v (c_v Q_v + 2
sum_{u<v} c_u Q_u)], summed per lane in the kernel with a running S = sum_{u<v} c_u Q_u.
At the vertices that keep the rule in the learned pass too (glass, mirrors, null boundaries,
cells with nothing learned) the pass survives with the rule applied to its *own* throughput,
which is not the rule's survival on the classic one: both enter P and Q
(:meth:`EARS.survivals`; taking the two for one decision read the cost 1.3 % high on
``specular_box`` and the glass shade's gain 1.22 instead of 0.82).  Every expectation is over
the learned pass's paths, unbiased for any survivals above zero; the test compares both with
classic passes (Welch t on the Cornell box and ``specular_box``; a mutant without the cross
terms reads the second moment a third low).  A first pass of one sample per pixel measures no
variance (a pixel's mean is its one sample), so the next pass stays classic and the
comparison waits for a learned pass.  The two relative variances are taken per pixel about
the pass's own mean and weighed by the relMSE's denominator of the *earlier* passes' mean
(:meth:`EARS.relative_variances`, :meth:`EARS.pass_denominators`): with the pass's own
samples in the denominators, the estimate read the first roulette pass's gain 2.04 (ajar
door) and 2.41 (indirect room) where the table's measured 0.92 and 1.44 (now read 0.85 and
1.30), which sent light through a gap and a window to splitting (0.72-0.98x ``nee_path``'s
efficiency).  The factors' V, read from the pixels' first samples, is low, and the first
table's roulette mild: an estimate after one classic pass of 2 spp read lower than the later
ones, so the classic passes go on until the pixels hold ``MATURE_SPP`` samples, and the first
roulette pass's estimate then decides.  The classic pass before it, with a table learned,
estimates on its own paths the learned roulette with that table the other way round (the
rule's survivals in P, the table's in Q, the rule where the table keeps it), its factors
scaled by each of ``ROULETTE_SCALES`` (the young table is mild by the image's variance V, read
low, a scale on every factor); where even the largest of those gains would send the render
plain at a roulette pass's estimate, it goes plain there, without the roulette pass and its
learned kernel (the rest of a 4-spp call at 96 px: 15-20 ms of a 32-spp render's 250-300).
Measured before those changes (its estimates the
inflated ones; 96 px, 512 spp, one roulette pass after the classic one; estimated efficiency of
the learned roulette against the rule, in the cost model's units): dark scene with a bright
light 2.4, indirect room 1.9, heavy mesh 1.5: learned; glossy scene 1.28, ``ajar_door`` 1.16,
the Cornell box 1.11 (max_depth 8), ``many_lights`` 1.04, ``specular_box`` 1.04,
``sharp_glossy`` 1.03, ``small_light`` 1.01, Veach's MIS scene 1.001, the caustic 0.92, the
lamp in a glass shade 0.82 (the learned roulette worse than the rule there, as measured before:
0.67-0.75x): plain.  Tried
first and not kept: a first-order model (each vertex's change alone, w^2 M (1/r - 1/q) from the
cells' moments): where most vertices change the changes compound (each vertex's copy cost holds
its subtree's), it read the rule's cost several times too far from the learned one on long
paths, and in the Cornell box the variance change with the wrong sign (measured in a draft
that also counted the deeper vertices twice, so no magnitudes are quoted).

**The plain kernel's copies of the first hit (policy ``auto``).**  Where the render goes plain,
its noise may be the first hit's light samples' (direct light: ``nee_path split=4`` lowers
``veach_mis``'s relMSE 3.9x for 2.8x the time), which no roulette touches and the statistics,
the continuation's, do not see.  So its first plain pass is a copy trial: the first
:meth:`EARS.trial_samples` of every pixel (``TRIAL_SAMPLES``, 2) take ``TRIAL_COPIES`` (2)
copies of the first hit (its light samples and continuation, ``nee_path``'s ``split``), the
others one, and the trial's samples measure, in the image as the relMSE sees it
(splatted with the film's filter, :meth:`EARS.measure_copies`), each pixel's variance (from the
difference of its even and odd samples' filtered means) and the share of it the copies average
(the filtered mean of half the difference of each camera sample's first two copies, whose
variance given the camera samples is that share): one copy's share V_1 and the rest V_0,
relative to the filtered pixels.  The plain kernel then takes the k in [1, ``split_max``] of
highest predicted efficiency 1 / ((V_0 + V_1 / k)(a + b k)) at its lower confidence bound
(:func:`copies_lower`, ``COPY_Z`` standard errors over tiles of the trial's pixels; more than
one only where that bound gains ``COPY_GAIN`` over one copy), in the cost model's units: a =
``CAMERA_COST``, b the rest of the throughput rule's cost per camera sample as the last roulette
(or classic) pass estimated it.  No trial where the copies could not gain ``COPY_GAIN`` even
holding all of the variance but the least share any trial measured (V_0 = ``TRIAL_V0`` V_1: a
camera sample cheap against its copy, the lamp in a glass shade, the Cornell box).  The
trial's lanes come first, sample-major (:meth:`Wavefront.trial_layout`), so a SIMD packet
takes one count of copies; where the film's filter is a box and the film larger than four
times ``TRIAL_PIXELS``, its pixels are a lattice (:func:`trial_pixels`).  Where the render
starts with a ``bound`` part (policy ``auto``), that part carries the trial
(:meth:`EARS.measure_bound`).  Else, where it is worth a part's fixed cost, the trial is a part
of its own and the rest of the call takes the copies chosen; else it shares its part with the
rest of the call (:meth:`EARS.part`).  (Before 2026-12-07 the trial was a whole pass, or the
first part of a call, of two copies: the Cornell box's 4-spp trial call took 32 ms against
``nee_path``'s 15 ms, ``many_lights``'s 32-spp one 123 ms against 84 ms, and a trial part cost
its own trace; then, until later that day, an eighth of its call, or a sixteenth as a part
of its own: 150 ms of ``many_lights``'s single 512-spp call.)  The
count and the weight 1/k are opaque in the kernel (one kernel for every k).  Measured:
``veach_mis`` 1.08-1.20x ``nee_path``'s efficiency with 4 copies chosen (0.83-0.94x with one),
the other plain-fallback scenes 0.75-1.05x, the trial's part 5-10 % of their 0.06-0.3 s renders
at 96 px (``benchmarks/results/ears_copy_gate``).  Measured before settling on this: per-pixel
box sums instead of the filtered image read ``small_light``'s copies' share of the variance 3-9x
too high (Mitsuba's Gaussian filter pools neighbouring pixels' samples, which averages the
copies' noise, independent between samples, more than the variation over a pixel footprint,
whose dark pixels next to the light hold its light): 2 copies lower the box sums' variance 1.7x
there and the image's 1.2x; the filtered pixels predict ``cornell_box``'s 4 copies' relMSE
3.2-3.5x lower (measured 3.42x) and ``small_light``'s 1.28-1.55x (1.32x).  The kernels' running
times of a one-copy and a two-copy part instead of the cost model varied too much between
repeats to choose from (the small parts' launches, and the trial's per-pixel sums, are in those
times).

**The first hit's copies in the megakernel.**  With ``split_depth`` 1 a lane makes floor(n + u)
copies of its first hit's light samples and continuation (n >= 1; above) and runs them one
after another: when a copy's path ends, the lane restarts from the first hit (kept in
registers) with the copy weight 1/m, and spends one iteration of the loop there taking light
samples of its own (so the loop holds one copy of the light-sample code; a second one, for
the restarting lanes, was no faster: 1.33-1.46x ``split=4``'s time against 1.18-1.48x in two
runs of ``benchmarks.ears_unit``), whose BSDF sample it continues with.  The camera ray is
shared, as with ``nee_path``'s fixed ``split``, and no lane is written, compacted or
gathered.  The first hit's record sums its copies' L_r, L_r^2 and cost in registers; the
deeper records are the first copy's.  The figures in this paragraph were measured with the
first hit's light samples shared by its copies.  A SIMD packet runs as long as its longest
lane, so lanes that draw different numbers of copies idle; the lanes of a packet are samples of
the same pixel, whose n is about the same.
Side runs, steady state (48 px, 256-spp passes after 8 learning ones, efficiency 1 / (per-pixel
relative variance x seconds) relative to ``nee_path rr=throughput``; split / roulette only):
indirect room 1.56/1.40, dark scene with a bright light 1.53/1.74, glossy scene 1.10/1.05,
ajar door 1.14/0.89, ``specular_box`` 0.79/0.79, lamp in a glass shade 0.63/0.77 (there the
copies, each of weight 1/n, are rouletted harder behind the first hit: 1.7x the continuation
rays for 0.68x the variance, where ``split=4`` with throughput roulette gives 3.7x the time for
0.26x).  Replicating the first hit instead (the wavefront below, then the tail kernel) was
0.67-0.76x in the indirect room.

**Path replication (the wavefront).**  Camera samples are processed in batches.  Per bounce one
kernel runs over the live lanes (:meth:`Wavefront.continuation`): the BSDF sample, its ray, the
MIS-weighted emission it finds (:meth:`VertexEstimator.emission`), the light samples at the new
vertex, all added to the lane's own sums (they go to its camera sample, one
``dr.scatter_reduce``, when the lane ends or splits), then n at the new vertex and u for its
rounding.  Then the next wavefront is built (:meth:`Wavefront.replicate`): lanes with zero
copies are dropped (``dr.compress``), lanes with k copies appear k times (an exclusive prefix
sum of the counts gives each parent's first slot; a scatter of marks and an inclusive prefix sum
give every slot its parent), and the state is gathered (inside the next bounce's kernel).  Each
lane carries its camera sample's index; when a batch has no live lane left, its camera samples
are splatted into the film (Mitsuba's ``ImageBlock``, with the film's reconstruction filter).
With every lane of the same policy (the throughput rule), a bounce of the wavefront costs about
1.8x a bounce of Mitsuba's megakernel in wall time (the state written and gathered, the
compaction's kernels, host synchronisations), a loop in one kernel 1.3-1.5x, so only the first
``split_depth`` vertices of a path are replicated (``split_depth`` >= 2; with 1, the default,
the first hit's copies run in the megakernel, above); the lanes then finish in one kernel, a
loop over the bounces with roulette only (:meth:`Wavefront.tail`; n clamped to 1; copies of a
split vertex draw their own BSDF sample, then reuse the one drawn with the light samples).
Splitting deeper was measured not to pay (indirect room and glossy scene, 128 spp, efficiency
relative to the baseline: 0.70x and 0.56x with splits up to the fourth vertex and records at
three, 0.90x / 0.67x as now; glossy scene with the batches sized as below, records at 1 / 2 / 3
bounces: 0.58x / 0.80x / 0.67x).

**Memory.**  At most ``max_lanes`` lanes are alive: where the copies of a bounce could pass the
cap, every n of that bounce is scaled by s = (cap - A) / sum n (A the live lanes), computed
before the rounding from the n alone (so still unbiased: each copy's weight is 1/(s n), or 1/m
where s n >= 1), which
bounds sum floor(s n + u) by s sum n + A <= cap.  Memory is then independent of the samples per
pixel.  The scaling changes the learned policy (every vertex of the bounce splits less and
rolls more), so a batch holds only as many camera samples as leave room for the copies: cap /
(1.1 D), D the largest (A + sum n) per camera sample of a bounce in the previous pass, divided
by the product of the cap's scalings before it in its batch (2 in the first pass, never more
than 2 ``split_max`` + 1).  With half the cap per batch, as before, the
learned splits of a 64-spp pass in the glossy scene (mean n 2.5 at the first hit) were scaled
by about 0.4, to no splitting at all.

**Cost.**  ``stats`` counts what was traced: camera rays, continuation rays, shadow rays, and
the camera samples, so comparisons can be made per ray as well as per second; and the bounces
whose factors the lane cap scaled (``capped_bounces``).

**Limits.**  JIT variants only (the wavefront is Dr.Jit arrays; ``nee_path`` refuses
``rr=adaptive`` in scalar variants in one line).  Vertices without a smooth lobe (glass,
mirrors, null boundaries) keep the throughput rule: their continuation is fixed by the incoming
direction, which a region's statistics pool over (learned roulette there: ``specular_box`` at
0.17x ``nee_path``'s efficiency, 0.39x without it).  Light that arrives only through glass (a
lamp in a glass shade: next-event estimation blocked, every contribution a rare BSDF-sampled
path) is heavy-tailed at the diffuse vertices before it.  Once learned (48 px, 256-spp batches
after 8 learning ones), ``rr=adaptive`` has there the variance of the throughput rule (relative
variance 0.241 against 0.243) for 1.3x its time: 1.13x the rays (learned survival 1 where the
throughput rule ends paths from ``rr_depth`` on) and the learned kernel's cost per ray (the
classic mode in the same kernel, records kept: 1.16x ``nee_path``'s time at equal rays).  No
constant lifts it without losing elsewhere (swept before the shrinkage: copies per cell 256 /
2048, ``RR_MARGIN`` 1 / 1.4 / 4, ``DECAY`` 0.8, ``LEARN_DEPTH`` 1 / 3; ``LEARN_DEPTH`` 1 gives
``glass_shade`` 0.84x and the indirect room 1.01x).  There the render now finds this itself
and goes on plain (above): 0.90-1.01x.  Tried and
not kept: path regeneration in the one-kernel pass (a lane whose path ends takes the next camera
sample from an atomic counter: with learning frozen 0.92x the roulette pass's time, but 1.09x
the classic pass's; with the records flushed inside the loop, learning: 1.13x in the indirect
room, 1.26x on the lamp in a glass shade, 0.88x in the glossy scene); falling back on the
throughput rule when the classic pass measured more efficient than the learned ones (one pass of
each is too noisy a measure: the ratio ranged 0.82-1.44 over repeats of the lamp in a glass
shade, and the first pass of a process carries 0.1 s of one-time Python costs).  The learned
roulette pass costs 1.3-1.4x ``nee_path``'s time in the indirect room for 1.1x its rays (the
classic mode in the same kernel: 1.0-1.07x at equal rays): the records (about a tenth) and, most
of it, paths of more varied length idling SIMD lanes: learned roulette keeps survival 1 wherever
n >= 1 (the throughput rule caps it at 0.95), so a packet of 16 lanes runs as long as its
longest path: 10.96 bounces on average against 8.45 for the classic rule (1.30x, the kernel's
1.31x) for paths of 4.92 against 4.46 bounces (lanes busy 45 % against 53 % of the iterations;
frozen table, 64 spp).  Measured again with the first hit's copies in the kernel (indirect
room, 96 px, 256 spp in doubling passes; the pass of 128 spp): the kernel in the classic mode,
records kept, 1.15x ``nee_path``'s time at equal rays; the learned pass 1.27x the classic one's
for 1.17x its continuation and 1.14x its shadow rays; learning frozen (no records) 0.92x the
learning pass's time in a 64-spp pass.  Not kept: a ``dr.ReduceMode.Local`` flush of the records
(whole renders 1.30 / 1.49 / 1.24x ``nee_path``'s time against 1.31 / 1.48 / 1.28x with
``Direct`` on the lamp in a glass shade, the indirect room and the ajar door) and survival capped
at 0.95 or 0.9 where n >= 1, as the throughput rule caps it (indirect room: time 1.47x -> 1.47x
/ 1.41x, relMSE 0.50 -> 0.55 / 0.60 of ``nee_path``'s: the long paths are not where the time
goes).  Nor does compacting the megakernel's paths that are still going (tried: at 4 and 8
bounces, ``dr.compress``, the state gathered, the vertex found again by its ray, a new kernel):
simulated from the lanes' path lengths it would run 0.68x the packet iterations, measured the
learned roulette pass took 622-640 ms against 620 ms without it, the classic one 472-632
against 490 (indirect room, 96 px, 128 spp, learning frozen): the time is not the idle lanes.
The learned pass's 1.33x ``nee_path``'s time, split up: this kernel in the classic mode 1.04x,
the factors' lookups and the smoothness query 1.05x, its 1.13x continuation rays, and 1.08x
left over.  The smooth test's BSDF-flags query costs 4 % of the pass; deciding from the lobe the
vertex's BSDF sample drew instead would bias the first hit's copies (their number would depend
on the first copy's own sample).  Per unit of work (rays, a shadow ray counting half) a split
pass with three replicated bounces cost about 1.7x Mitsuba's megakernel on the LLVM backend
(glossy scene, learned policy, learning frozen: 2.1 s against nee_path's 0.45 s for 2.9x its
rays): the
replicated bounces (state written and gathered, compaction, host synchronisations) and a tail
loop whose SIMD packets idle while their last lanes finish.  Measured and not kept: compacting
the tail every 4 bounces (kernel time 0.72x, but the extra launches and traces ate it: 0.99x
overall); each region's splitting variance from the spread of split copies instead of the spread
of all its records (0.85 of it in the glossy scene: no change in efficiency).  In the cost
model's units the learned policy is 1.26x ``nee_path``'s efficiency in the glossy scene, no
better than splitting 4 ways at the first hit; the efficiency figures in
``benchmarks/results/ears`` include all of it."""
from __future__ import annotations

import contextlib
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from ..common import (depth_limit, emitted, host, host_view, lnot, luminance, record_once,
                      safe_div, widen)
from .learning import RegionGrid, film_shape, relmse_denominator, sensor_view
from .roulette import roulette, throughput_survival

#: bounces whose vertices keep records (statistics of L_r and cost per region); one more
#: bounce is replicated, the rest runs in the tail kernel
LEARN_DEPTH = 2
#: copies the scene needs before learned factors replace the throughput rule
MIN_VISITS = 32
#: a render call that learns is rendered in parts, learning between them (:meth:`EARS.part`):
#: the first this share of the call's samples (1: the whole call in one part), each later one as
#: many samples as the parts before it, the ``LEARN_PARTS``-th the rest.  So the mode a part's
#: estimate decides (the plain kernel where learning does not pay) takes effect within the
#: call, and a render of one call (``mi.render(..., spp=N)``) is not rendered in a mode that
#: its first part already found worse.  Before (a quarter of the first call classic, the rest
#: learned in one part, also where that part's own estimate found learning not worth it), one
#: call at 96 px (``benchmarks.ears --single``, 4 repeats, efficiency relative to
#: ``nee_path`` at 32/128/512 spp) was 0.60/0.59/0.60x on Veach's MIS scene, 0.50/0.57/0.96x
#: on ``small_light``, 0.66/0.78/0.72x on the lamp in a glass shade and 1.12/1.11/1.13x in the
#: indirect room; with the parts 0.54/0.68/0.83x, 0.63/0.85/1.00x, 0.86/0.92/0.98x and
#: 1.22/1.31/1.40x (what is left where learning does not pay: the learning parts at 1.5-1.8x
#: the plain kernel's time per sample on short paths, and 15-25 ms per call of tracing and
#: learning)
FIRST_PART = 1 / 16
LEARN_PARTS = 5
#: whether :meth:`EARS.part` weighs a part's fixed cost against the samples left before
#: splitting off another deciding part (tests of the parts' sizes turn it off: it depends on
#: measured times)
WEIGH_PART_COST = True
#: copies the cell of the median copy holds (:func:`median_copy_cell`, over the fine cells, their
#: statistics as decayed, after a learned pass) when learning stops: the later passes keep the
#: factors and record nothing (the records cost 8 % of a roulette pass in the indirect room,
#: 654 ms against 604 ms frozen, for no change in variance once the cells hold about a hundred
#: copies: relative MSE 0.486 learning, 0.485 frozen, 96 px, 128-spp passes after 128 spp of
#: learning).  Over the cells' median instead (before 2026-12-06) the dark scene never settled;
#: side by side with it (96 px, the benchmark's seeds, 4 repeats at 32/128 spp, 2 at 512): the
#: same images at 32 and 512 spp (the last pass's table is the same), at 128 relative MSE
#: 1.00-1.05x for 0.92-0.98x the time (indirect room 1.04x the efficiency, dark scene 1.07x,
#: heavy mesh 1.02x, glossy 1.00x, ajar door 1.04x); at 512 spp 0.95-0.97x the time
SETTLED_COPIES = 64
#: learned passes in a row in the same mode (a call's parts count one each; a change of mode,
#: ``auto``'s split trial or ``measured``'s alternation, starts again from one) before learning
#: may stop: the policy and the
#: statistics recorded under it converge over a few (indirect room, 96 px: 5.43, 5.12, 5.04
#: continuations per camera sample settled after one, two, three, for the same variance)
SETTLED_PASSES = 2
#: weight, in copies, of the parent level's moments in a cell's (fine: its coarse cell's;
#: coarse: the scene's): a cell's second moment estimated from few heavy-tailed copies reads low
#: (none of the rare large ones seen), and zero where none was seen
PRIOR_VISITS = 32
#: resolutions of the fine and the coarse grid (cells along the scene's longest side)
FINE, COARSE = 32, 8
#: weight of older statistics after each pass (the policy behind a vertex changes)
DECAY = 0.5
#: cost of a shadow ray relative to a continuation (closest-hit) ray and its vertex
SHADOW_COST = 0.5
#: the roulette factor is raised by this much: a region's second moment is estimated from few,
#: heavy-tailed samples and reads low more often than high, and roulette that is too aggressive
#: costs more than roulette that is too mild
RR_MARGIN = 2.0
#: cost of a camera sample before its first bounce (camera ray, its generation and the film
#: splat) in the same unit: what splitting at the first hit saves per copy
CAMERA_COST = 2.0
#: how a pass runs: ``classic`` (nothing learned, or measured best: the throughput rule at every
#: vertex, records kept), ``roulette`` (the learned factors clamped to one: roulette only, every
#: path in one kernel), ``split`` (the learned factors, splitting by replication at the first
#: ``split_depth`` vertices), ``plain`` (the learned roulette measured not to pay for its
#: kernel, :meth:`EARS.compare`: the integrator's own kernel with the throughput rule, no
#: records, for the rest of the render), ``bound`` (a render's first part where the throughput
#: rule ends no path, :attr:`EARS.bounding`: the plain kernel, its paths' costs counted,
#: :class:`CostCounter`, to bound what learning could gain, :meth:`EARS.bound_gain`).  The
#: classic and roulette passes run in Wavefront.roulette_kernel.
MODES = ("bound", "classic", "roulette", "split", "plain")
#: time per unit of work of a learning roulette pass relative to the plain kernel's (Mitsuba's
#: megakernel, the throughput rule): its records, the factors' lookups and the pixel statistics
#: (Veach's MIS scene, 96 px, 256 spp: 108.6 ms against 86.3 ms for 0.95x the rays).  A
#: gain below it does not pay for learning (:meth:`EARS.compare`)
KERNEL_COST = 1.3
#: the most efficiency a render may give away by going plain on a bound part's bound
#: (:meth:`EARS.bound_gain`): where the learned roulette, at its bound, would be at most
#: 1 / (1 - BOUND_LOSS) as efficient as the plain kernel, no learning part is run to estimate
#: it.  The bound is far from the gain where the bound is near ``KERNEL_COST`` (``small_light``,
#: ``many_lights``, Veach's MIS scene, 96 px: bounds 1.31-1.34, roulette passes' estimates
#: 1.00-1.03), and the classic and roulette parts cost a part's fixed cost each, a trace of
#: the learned kernel (4-6 ms at 96 px; 40-50 ms with ``many_lights``'s thousands of emitters,
#: a sixth of a 128-spp render), and their own samples in that kernel
BOUND_LOSS = 0.05
#: the modes the ``measured`` policy chooses between (``classic`` runs only while nothing is
#: learned: measured against the learned modes, one early pass's heavy-tailed variance made it
#: the choice in the indirect room, at 0.76x the efficiency of roulette)
LEARNED_MODES = ("roulette", "split")
#: ``split_policy``: ``never`` (roulette only), ``always`` (split once learned), ``measured``
#: (each learned mode once, then the more efficient as timed), ``auto`` (a split pass after the
#: first roulette pass estimates the roulette: split while it pays; the default)
POLICIES = ("never", "always", "measured", "auto")
#: time per unit of work of a split pass relative to a roulette pass (the first hit's copies
#: run one after another in a lane, so a SIMD packet waits for its lane of most copies; seconds
#: per (rays, a shadow ray counting half, a camera sample two)): measured 1.02-1.26 with the
#: same frozen table, learned under policy ``always`` (``benchmarks.ears_split_cost``: 96 px,
#: 7 alternating 64-spp passes of each mode; two runs, indirect room 1.09 / 1.26, ajar door
#: 1.25 / 1.23, glossy 1.11 / 1.02, heavy mesh 1.10 / 1.13).  Policy ``auto`` splits
#: while the split pass's estimated gain over the roulette is at least this.  At 1.05 (its
#: value until 2026-12-07, measured 1.04-1.06 on lighter split tables) one call of 512 spp in
#: the indirect room split on an estimate of 1.052 (seed 0), its rest at 1.5x the roulette's
#: cost per camera sample and 1.10x its time per unit of work: 0.98x ``nee_path``'s
#: efficiency in one call at 512 spp against 1.18x with this value (3 repeats each, side by
#: side); at 128 spp and in doubling calls the room's decisions the same, glossy (doubling
#: calls, 128/512 spp) 1.01/1.12x against 1.10/0.97x
SPLIT_COST = 1.10
#: policy ``auto``: the learned roulette's estimated gain over the throughput rule from which a
#: split pass is tried (below it the render goes on plain, as with ``never``, where the gain
#: is below ``KERNEL_COST``).  Splitting's estimated gains over the roulette: 1.55 (ajar door),
#: 1.27 (indirect room), 1.22 (glossy scene), 0.98-1.0 (heavy mesh, dark scene; 48 px, 128-spp
#: passes after learning); below 1.15 the splitting would have to gain 1.2 or more to pay for
#: the learned kernel.  Tried and not kept (2026-12-06, 96 px, 4 repeats, efficiency relative to
#: ``nee_path`` side by side with this rule, at 32/128/512 spp):
#: splitting tried at every roulette gain (1.0): the ajar door (roulette 1.07-1.10 at 512 spp,
#: splitting 1.4-1.7 over it) +0.10 at 512 and the Cornell box +0.07/+0.08 at 128/512, but the
#: trial pass at half the efficiency where splitting does not pay: Veach's MIS scene 0.64/0.67
#: against 0.81/0.86, ``small_light`` 0.62 against 0.77 at 32, ``many_lights`` -0.04 to -0.10;
#: the trial in the next roulette pass instead of a whole split pass (one row of pixels in four
#: split and estimated the roulette, the other rows the rule; random samples instead made the
#: pass cost a split pass's, each SIMD packet waiting for its lane of most copies): cheaper where
#: splitting does not pay (dark scene +0.12/+0.08/-0.05, heavy mesh +0.13/+0.04/+0.03), a pass
#: later where it does (ajar door -0.10/-0.13/+0.01, glossy -0.07/-0.04/+0.02, indirect room
#: -0.01/-0.09/-0.02); with it at every roulette gain, its few samples read splitting's gain
#: high often enough to split ``specular_box`` and ``sharp_glossy`` at 32 spp (0.52x and
#: 0.17x with the split kernel's compilation in the time)
SPLIT_TRY = 1.15
#: policies ``never`` and ``auto``: the samples per pixel the classic passes take before the
#: first roulette pass, whose estimate of the learned roulette's gain over the throughput rule
#: (:meth:`EARS.compare`) decides on the plain kernel or the split trial.  The factors hold the
#: image's relative variance V, read from the pixels' samples so far, and the first ones read it
#: low (the young table's roulette is then mild, its paths long): after one classic pass of 2
#: spp the first estimate read below the later ones, and as low at 256 px as at 96 px, where a
#: cell holds a seventh of the copies (glossy scene 1.03-1.06 and 0.99-1.04): what is young is
#: the pixels' variance, not the cells' statistics.  96 px, 3 renders each, estimates after 2
#: spp of classic passes / after 4 (two passes of 2) / of the last pass (16 spp, after 32 of
#: learning): window 0.82-0.84 / 0.97-0.98 / 1.17-1.19, ajar door 0.84-0.88 / 0.90-0.96 /
#: ~1.1, glossy 0.99-1.04 / 1.10-1.17 / 1.21-1.23, indirect room 1.22-1.42 / 1.46-1.74 /
#: 1.81-1.83, heavy mesh 1.35-1.39 / 1.46-1.49 / 1.54-1.56, dark scene 1.84-2.26 / 2.31-2.41 /
#: 2.24-2.35 (one classic pass of 4 spp: 0.92-0.97, 0.92-0.94, 1.07-1.10, -, 1.41-1.44).
#: Before (2026-12-07) a second roulette pass decided instead, its estimate as mature as this
#: one's: the pass it replaces ran the young table's learned kernel at 1.7-2x the plain
#: kernel's time per sample (window, 96 px, 2 spp: 21.5 ms against 11; a classic pass 12.7)
MATURE_SPP = 4
#: policies ``never`` and ``auto``: the scales s of the learned factors (s n,
#: :meth:`EARS.survivals`) at which a classic pass with a table learned, before the pixels
#: hold ``MATURE_SPP`` samples, estimates the learned roulette on its own paths; where the
#: largest of those gains (:meth:`EARS.compare`) would send the render plain at a roulette
#: pass's estimate (below ``SPLIT_TRY``, under ``never`` below ``KERNEL_COST``), it goes
#: plain there, without the roulette pass.  Why scales: the young table is mild by the
#: image's variance V (n ~ 1 / sqrt(V)), read low from the pixels' first samples; at 96 px
#: sqrt(V after 2 spp / V settled) measured 0.28 (ajar door), 0.37 (window), 0.39 (indirect
#: room), 0.56 (glossy), 0.57 (dark scene), 0.73 (caustic), 0.86 (heavy mesh), hence 1 to 1/4
#: in factors of two.  Unscaled the young table read below the later roulette passes (window
#: 0.82-0.84 against 1.04-1.19, indirect room 1.22-1.42 against 1.62-1.83); the largest over
#: the scales reads as high or higher (96 px, 3 renders each, the largest / the first
#: roulette pass's where one ran): window 1.12-1.16 / 0.98, ajar door 1.01-1.07, caustic
#: 0.86-0.98, ``specular_box`` 0.97-0.98, glass shade 0.74-0.75 (plain at once, the window in
#: two renders of three), Cornell box (max_depth 8) 1.21-1.30 / 1.08-1.10, glossy 1.25-1.34 /
#: 1.13-1.14 (plain after the roulette pass), indirect room 1.53-1.92 / 1.46-1.61, dark scene
#: 2.90-2.93 / 2.34-2.59, heavy mesh 1.41-1.59 / 1.51-1.53 (learned, as before)
ROULETTE_SCALES = (1.0, 0.5, 0.25)
#: policy ``auto``: once the render goes plain, its first plain pass's trial samples
#: (``TRIAL_SAMPLES``) take this many copies of the first hit (``nee_path``'s ``split``), and
#: measure how much of a camera sample's variance they average (:meth:`EARS.measure_copies`),
#: so that the plain kernel's copies can be chosen: where the first hit's light samples carry
#: the noise (direct light), 2-4 copies pay
TRIAL_COPIES = 2
#: the copy trial's samples per pixel that take ``TRIAL_COPIES`` copies (the first of every
#: pixel in its pass, an even count: :meth:`EARS.trial_samples`); the others take one.  Its
#: cost does not grow with its call (a whole call of two copies was 2x ``nee_path``'s time on
#: the Cornell box; at 512 spp in 32-spp calls, ``many_lights``'s trial call was 123 ms
#: against 84; a share of the call, an eighth, or a part of the first part's size, a
#: sixteenth, cost 150 ms of one 512-spp call's 1015 ms, ``nee_path`` 778 ms).  Its standard
#: errors shrink with the film's pixels (:func:`copies_lower`), 0.05-0.08 at 96 px
TRIAL_SAMPLES = 2
#: the copy trial's pixels, at least, where the film's filter is a box: a film of more than
#: four times as many takes its trial on a lattice of every s-th pixel of every s-th row, s the
#: largest stride that leaves this many (:func:`trial_pixels`), so that the trial's cost does
#: not grow with the film (at 96 px, s = 2: ``veach_mis`` chose its 4 copies in 10 renders of
#: 10 either way).  A wider filter pools its neighbours' samples into a pixel, which a lattice
#: would leave out (``many_lights``'s predicted gain of copies, 1.28-1.37 over ten trials on
#: every pixel, read 1.51-2.49 on a lattice of stride 2): its trial takes every pixel
TRIAL_PIXELS = 2048
#: the predicted efficiency gain over one copy from which the plain kernel takes more (the
#: cost model reads a copy's cost relative to the camera sample's up to 2.8x low on directly
#: lit scenes, e.g. ``veach_mis``, so the predicted gains run high: 1.7-1.8 there against
#: ``split=4``'s measured 1.3-1.5; ``small_light`` 0.99-1.16 and ``sharp_glossy`` 1.09-1.2,
#: measured 0.6 and 1.0-1.1; ``cornell_box`` 1.03-1.14, measured 1.03-1.14)
COPY_GAIN = 1.3
#: the copies' gate (:meth:`EARS.go_plain`): a copy trial is run only where copies could gain
#: ``COPY_GAIN`` with V_0 / V_1 this small, the least the trials measured over the fourteen
#: scenes (``veach_mis``, 0.025-0.07; the Cornell box 0.09, ``many_lights`` 0.22,
#: ``small_light`` 0.5).  With V_0 = 0 the Cornell box's costs (b / a 2.2) read a possible
#: 1.37 and ran its trial, 20 ms of a 4-spp call of 50 ms (``nee_path`` 30 ms), for copies
#: its point estimate put at 1.09-1.16 (one copy); at this share they could gain 1.22 at most
TRIAL_V0 = 0.025
#: the copy trial's predicted gains are taken at their lower confidence bound, this many
#: standard errors below the estimate (:func:`copies_lower`): the trial's few samples per
#: pixel read ``many_lights``'s gain 1.27-1.42 over ten trials (96 px, 2 trial samples per
#: pixel, standard error 0.05-0.08), so about half of its renders took 3-4 copies, half one,
#: and their mean relMSE over their median time was 0.86x ``nee_path``'s efficiency at 128 spp
#: (copies 1.1x, one copy about 1.0x); Veach's MIS scene, whose copies pay 1.3-1.5x, read
#: 1.72-2.03 (bounds 1.56-1.77)
COPY_Z = 2.0
#: the copy trial's pixels are pooled in tiles of this many pixels a side for its standard
#: errors (the film's filter correlates neighbouring pixels)
COPY_TILE = 4
#: atomic scatter-adds (the default may replicate the target per thread, with its size baked
#: into the kernel: a recompilation whenever a wavefront's width changes)
DIRECT = dr.ReduceMode.Direct
#: the megakernel's records, flushed when a lane ends: the lanes of a SIMD packet are samples of
#: one pixel, so their atomics mostly hit the same cells and contend; the grids (fixed sizes)
#: are expanded to one copy per thread instead and written without atomics (LLVM; other
#: backends read it as Auto).  Veach's MIS scene, 96 px: the kernel 54 ms instead of 64 ms
#: (57 ms with Local, 46 ms without records), whole renders 1.46x nee_path's time instead of
#: 1.54x; no change where paths are long (the indirect room 1.49x both)
FLUSH = dr.ReduceMode.Expand


@contextlib.contextmanager
def pass_clock():
    """Seconds of the block, all launched work finished, less the time Dr.Jit spent compiling
    kernels (a mode's first pass compiles its kernels: counted, a fast mode would read slow on
    a small pass), and its fixed cost: the seconds not spent running kernels nor compiling them
    in the LLVM backend (tracing, code generation, launches: what a part of a render call costs
    whatever its size, :meth:`EARS.part`) and the kernels' running time.  Yields a list that
    holds the three after the block.  Where the caller already records the kernel history, it
    is left alone, the seconds are wall time and the other two None."""
    out = [0.0, None, None]
    own = not dr.flag(dr.JitFlag.KernelHistory)
    if own:
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()                        # (reading it clears it)
    t0 = time.perf_counter()
    try:
        yield out
    finally:
        dr.sync_thread()
        out[0] = time.perf_counter() - t0
        if own:
            hist = dr.kernel_history()
            dr.set_flag(dr.JitFlag.KernelHistory, False)
            codegen, backend, running = (sum(k.get(key, 0.0) for k in hist) / 1000.0 for key in
                                         ("codegen_time", "backend_time", "execution_time"))
            out[1], out[2] = max(out[0] - backend - running, 0.0), running
            out[0] = max(out[0] - codegen - backend, 0.0)


def seed_mix(*xs: int) -> int:
    """A 32-bit seed from integers (a multiplicative hash; distinct for distinct tuples in
    practice, and decorrelated by the sampler's own seeding)."""
    h = 0x811C9DC5
    for x in xs:
        h ^= int(x) & 0xFFFFFFFF
        h = (h * 0x01000193) & 0xFFFFFFFF
        h ^= h >> 15
        h = (h * 0x2C1B3C6D) & 0xFFFFFFFF
        h ^= h >> 12
    return h


class EARS:
    """The learned state of one scene: per-region statistics and factors, per-pixel values.

    ``rr_min``, ``split_max``: the clamp of n; ``rr_depth``: the throughput rule's first depth
    (used where nothing is learned).  ``forced``: a function (sampler, active) -> n that
    replaces the learned n at every vertex (tests: random or maximal factors)."""

    def __init__(self, scene, rr_min: float, split_max: int, rr_depth: int,
                 split_depth: int = 1, policy: str = "never", max_depth: int = -1):
        # a fine and a coarse grid (roulette: the larger factor of the two cells; splitting: the
        # fine cell's where it has enough copies, else the coarse one's); statistics: sum L_r^2,
        # sum L_r, copies, sum cost
        self.grid = RegionGrid(scene, stats=4, resolution=FINE)
        self.coarse = RegionGrid(scene, stats=4, resolution=COARSE, size=1 << 12)
        self.rr_min, self.split_max, self.rr_depth = float(rr_min), int(split_max), int(rr_depth)
        #: the paths' longest (-1: unlimited): where it is at most ``rr_depth`` the throughput
        #: rule ends no path, and a ``bound`` part bounds the learned roulette's gain
        #: (:meth:`bound_gain`)
        self.max_depth = int(max_depth)
        self.f_var = mi.Float(np.full(self.grid.size, -1.0, np.float32))
        self.f_var_coarse = mi.Float(np.full(self.coarse.size, -1.0, np.float32))
        #: a learning pass's estimate of its alternatives' costs (``Wavefront.kernel_batch``)
        self.pass_cost_c = np.zeros(0)
        #: the learned roulette's efficiency relative to the throughput rule's, as estimated
        #: from the last roulette pass (:meth:`compare`)
        self.gain = None
        #: the bound on ``gain`` that a classic pass measured where the throughput rule ends no
        #: path (:meth:`bound_gain`); None where it measured none
        self.gain_bound = None
        #: splitting's efficiency relative to the learned roulette's, as estimated from the
        #: last learning split pass (policy ``auto``, :meth:`compare`)
        self.split_gain = None
        #: a classic pass's estimates of the learned roulette's gain over the rule with the
        #: young table at each of ``ROULETTE_SCALES`` (:meth:`compare`): the largest, and the
        #: scale it was read at; None before one
        self.young_gain = None
        self.gain_scale = None
        #: set once the prediction found the learned roulette not worth its kernel: the passes
        #: then run ``plain`` (the integrator's own kernel, the throughput rule, no records)
        self.plain = False
        #: copies of the first hit's light samples and continuation per camera sample in the
        #: plain kernel (``nee_path``'s ``split``): 1, or under policy ``auto`` the count of
        #: highest predicted efficiency after the copy trial (:meth:`measure_copies`)
        self.copies = 1
        #: policy ``auto``, plain: the copy trial (a plain pass, or the bound part, whose first
        #: samples of every pixel take ``trial_copies`` copies, their variance measured) still
        #: to run (:meth:`measure_bound`, :meth:`go_plain`); what it
        #: measured: (the variance the copies share, one copy's share), relative, the trial's
        #: pixels' mean; and the throughput rule's cost per camera sample, as the last
        #: roulette pass (or the classic pass, :meth:`bound_gain`) estimated it
        self.copy_trial = False
        self.trial_copies = TRIAL_COPIES
        self.copy_var = None
        #: the trial's sums per tile (``COPY_TILE``) of the pixels' relative variance and D^2
        #: (:func:`copies_lower`)
        self.copy_tiles = None
        self.rule_cost = None
        #: the copy trial's pass: its pixels' even and odd samples and the copies' half
        #: differences, filtered (``Wavefront.render``, :meth:`measure_copies`)
        self.trial_block = None
        #: each fine cell's coarse cell (the last record written there): the parent its moments
        #: are shrunk towards
        self.parent = dr.zeros(mi.UInt32, self.grid.size)
        dr.eval(self.parent)    # (a buffer before a kernel scatters into it, as the stats)
        self.shape = self.view = None
        self.passes = 0
        #: largest (live lanes + sum of n) per camera sample of a bounce in the last pass
        self.lane_demand = 2.0
        self.learned = False
        #: vertices of a path (from the first hit) that may split, by replication, in "split"
        #: passes; the rest run in the tail kernel with roulette only
        self.split_depth = int(split_depth)
        #: how the passes run (``POLICIES``) and the mode of the next pass (``MODES``), with
        #: the efficiency measured for each mode so far (1 / (relative variance x cost) per
        #: camera sample of its last pass)
        self.policy = policy
        self.mode = "bound" if self.bounding else "classic"
        # (policy auto: the bound part carries the copy trial, for the case it goes plain)
        self.copy_trial = self.mode == "bound" and policy == "auto"
        self.measured = {}
        self.last_pass = {}
        self.forced = None
        #: set False to freeze what was learned
        self.learning = True
        #: set once the cells hold enough copies (``SETTLED_COPIES``) after ``SETTLED_PASSES``
        #: learned passes in the same mode: learning stops
        self.settled = False
        self.learned_passes = 0
        #: the learned mode those passes ran in
        self.learned_mode = None
        #: the last deciding part (:meth:`part`; of an earlier call where a call's first part
        #: asks): (its fixed seconds, its kernels' running seconds per sample per pixel, i.e.
        #: per spp over the film); None before any
        self.part_cost = None

    # ---- per-pixel state -----------------------------------------------------------------
    def film(self, shape, view=None):
        """Per-pixel state for a film of ``shape`` (h, w) seen from ``view``
        (:func:`~integrators.sampling.learning.sensor_view`; reset when either changes)."""
        if self.shape != tuple(shape) or self.view != view:
            self.shape, self.view = tuple(shape), view
            n = shape[0] * shape[1]
            self.pix_s1 = np.zeros(n)
            self.pix_n = np.zeros(n)
            self.inv_pixel = mi.Float(np.zeros(n, np.float32))
            self.learned = False
            # (the factors need this film's pixel values: one classic pass measures them; the
            # modes' measured passes were of the other film's pixels)
            self.settled, self.learned_passes = False, 0
            if self.mode in LEARNED_MODES:
                self.mode = "classic"
            # (nor are the modes' measured passes and estimated gains this film's)
            self.last_pass, self.measured = {}, {}
            self.gain = self.split_gain = None
        self.pass_s1 = dr.zeros(mi.Float, self.shape[0] * self.shape[1])
        self.pass_s2 = dr.zeros(mi.Float, self.shape[0] * self.shape[1])
        self.pass_cost = 0.0
        #: the pass's cost had every path ended at its first hit after the hit's light samples
        #: (:meth:`bound_gain`; ``bound`` parts)
        self.pass_cost_first = 0.0
        #: the alternatives' (:attr:`alternative`, at each scale) per-pixel sums of their
        #: second moments and their costs, estimated on the pass's paths (sized by the kernel)
        self.pass_s2c = []
        self.pass_cost_c = np.zeros(0)

    def part(self, spp: int, done: int, k: int) -> int:
        """The samples per pixel of part ``k`` of a render call of ``spp``, ``done`` of them
        rendered.  While a part is to decide the mode (:attr:`deciding`) a call is rendered in
        parts of doubling size (the first ``FIRST_PART`` of the call, two per pixel at least:
        one measures no variance; then as many as rendered so far, the ``LEARN_PARTS``-th the
        rest), learning between them, so that the mode a part's estimate decides (the learned
        roulette, splitting, or the plain kernel) renders the rest of the call; else the rest
        in one part.  A part after the first is split off only where the samples left are
        worth its fixed cost (``part_cost``, the last part's: tracing, code generation,
        launches and learning; ``WEIGH_PART_COST``): a decision switches the rest to a kernel
        that saves at most the share 1 - 1 / ``KERNEL_COST`` of the learned kernel's running
        time, so where that saving on the samples left is less, the rest is one part, and its
        estimate decides the next call's mode.  The copy trial (plain, :attr:`copy_trial`) is
        such a part, of ``TRIAL_SAMPLES``, where the same rule finds it worth its fixed cost
        (copies that pay, as a kernel 1.3x as efficient would, save that share of the rest's
        time; in a call's first part, by the last deciding part's cost; without one, the call
        is one part): so that the rest of the call takes the copies it chooses (one call of N
        spp: ``veach_mis``'s copies pay 1.3-1.5x).  Else the trial's samples are the first of
        a part that holds the rest of the call (its layout and filtered sums then cost that
        part 3-4 %: the Cornell box, 96 px, 16 spp, 54 ms against 52)."""
        left = spp - done
        if not self.deciding or k + 1 >= LEARN_PARTS:
            return left
        trial = self.mode == "plain"        # (deciding while plain: the copy trial)
        weigh = WEIGH_PART_COST and self.part_cost is not None
        if k == 0 and trial and not weigh:
            return left
        if (k > 0 or trial) and weigh:
            fixed, per_spp = self.part_cost
            if left * per_spp * (1.0 - 1.0 / max(KERNEL_COST, 1.0)) < fixed:
                return left
        first = max(2, int(round(spp * FIRST_PART)))
        size = min(TRIAL_SAMPLES if trial else first if k == 0 else done, left)
        return left if left - size < 2 else size

    @property
    def deciding(self) -> bool:
        """Whether the next pass, learning, decides the mode of the ones after it: the classic
        pass (nothing learned), a roulette pass before any has estimated the throughput rule
        (policies ``never`` and ``auto``: the plain kernel or not), ``auto``'s split trial,
        ``measured``'s passes until each learned mode has been timed once.  Later passes
        renew the estimates too, but a call is then rendered in one pass: the statistics
        decay by ``DECAY`` after every pass, whatever its size, so parts in every call would
        shorten what the regions remember (the indirect room, 24 px, calls of 32 spp in parts
        while learning: 13 learned passes in three calls, not settled)."""
        if self.mode == "plain":        # (the copy trial, see part)
            return bool(self.copy_trial)
        if self.mode == "bound":
            return True
        if not self.recording:
            return False
        if self.mode == "classic":
            return True
        if self.policy == "measured":
            return any(m not in self.measured for m in LEARNED_MODES)
        return (self.mode == "roulette" and self.gain is None and self.policy != "always") \
            or (self.mode == "split" and self.split_gain is None and self.policy == "auto")

    @property
    def bounding(self) -> bool:
        """Whether a render starts with a ``bound`` part (:meth:`bound_gain`): under the
        policies that go plain (``never``, ``auto``), where the throughput rule ends no path."""
        return self.policy in ("never", "auto") and 0 <= self.max_depth <= self.rr_depth

    @property
    def recording(self) -> bool:
        """Whether a pass records statistics and learns from them: not with factors given
        (``forced``), frozen (``learning`` False) or ``settled``."""
        return self.learning and not self.settled and self.forced is None

    # ---- in the kernel -------------------------------------------------------------------
    def factor(self, si, beta, eta, depth, pixel, sampler, active, split=None, smooth=None,
               raw=False):
        """n(x) at the vertex ``si`` reached with throughput ``beta`` (before clamping to the
        lane cap), whether the vertex falls back on the throughput rule, and its cell.  n is
        zero where ``active`` is false.  ``split``: whether n may exceed one (default: in
        ``split`` passes).  ``raw``: also return the learned roulette factor w f_m before its
        clamp (linear in beta: what another throughput would get, :meth:`survivals`).  Where
        nothing is learned n is 1 and the throughput rule is applied by the copy after its BSDF
        sample (:meth:`Wavefront.continuation`), as Mitsuba's ``path`` does: the sample's own
        weight then counts in the survival, and no more continuations are traced than the
        classic roulette traces.  ``smooth``: whether
        the vertex's BSDF has a smooth lobe, where the caller knows it (:meth:`Wavefront.light`:
        the flags query is a call over the scene's BSDFs, 3 % of a roulette pass)."""
        cell = (self.grid.cell_of(si), self.coarse.cell_of(si))
        classic = mi.Bool(False)
        n_r = None
        # (a classic pass that estimates the learned roulette: the table's factors, raw)
        estimating = raw and self.mode == "classic" and self.alternative == "learned"
        if self.mode == "classic" and self.forced is None and not estimating:
            n, classic = dr.full(mi.Float, 1.0, dr.width(active)), mi.Bool(True)
        elif self.forced is not None:
            n = dr.clip(self.forced(sampler, active), self.rr_min, self.split_max)
        else:
            f_m = self.grid.lookup(cell[0], active)
            fine = f_m >= 0
            # (the coarse cell's where the fine one has no records; the fine cell's moments are
            # already shrunk towards its coarse cell's, see factors)
            f_m = dr.select(fine, f_m, self.coarse.lookup(cell[1], active & lnot(fine)))
            w = luminance(beta) * dr.gather(mi.Float, self.inv_pixel, pixel, active)
            n = n_r = w * f_m
            if self.mode == "split" if split is None else split:
                # (roulette passes clamp n to one: no splitting factor)
                coarse = dr.gather(mi.Float, self.f_var_coarse, cell[1], active & lnot(fine))
                f_v = dr.select(fine, dr.gather(mi.Float, self.f_var, cell[0], active & fine),
                                coarse)
                n = dr.select(n < 1.0, n, dr.maximum(w * f_v, 1.0))
            # a vertex without a smooth lobe (glass, mirror, null) continues in the one direction
            # its incoming ray dictates: a region's statistics, pooled over every incoming
            # direction, do not describe it; the throughput rule does
            if smooth is None:
                smooth = mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Smooth)
            classic = (f_m < 0) | lnot(smooth)
            n = dr.select(classic, 1.0, dr.clip(n, self.rr_min, self.split_max))
            # (the learned roulette's own rule vertices: a raw factor below zero)
            n_r = dr.select(classic, -1.0, n_r)
            if estimating:      # (the pass itself classic: n one, the rule at every vertex)
                n, classic = dr.full(mi.Float, 1.0, dr.width(active)), mi.Bool(True)
        beta_nz = dr.any(mi.unpolarized_spectrum(beta) != 0)
        n = dr.select(active & beta_nz, n, 0.0)
        if raw:
            return n, classic, cell, (n if n_r is None else n_r)
        return n, classic, cell

    def throughput_roulette(self, beta, eta, depth, classic, sampler, active):
        """The throughput rule after a copy's BSDF sample where its vertex had nothing learned
        (``classic``), from ``rr_depth`` on: the shared rule of
        :func:`~integrators.sampling.roulette.roulette` (elsewhere the depth it sees is 0, below
        any ``rr_depth``).  Returns (beta, active and surviving)."""
        u = sampler.next_1d(active)
        return roulette("throughput", self.rr_depth, 0.0, beta, eta,
                        dr.select(classic, depth, 0), u, active)

    def classic_survival(self, beta, eta, depth, pre):
        """The throughput rule's survival for the continuation from a vertex reached with
        ``beta``, ``eta`` at ``depth``, applied after its BSDF sample ``pre`` (sample, weight)
        as in a classic pass (:meth:`throughput_roulette`): min(max(beta w) eta'^2, 0.95) from
        ``rr_depth`` on, else 1."""
        bs, wt = pre
        q = throughput_survival(beta * wt, eta * bs.eta)
        return dr.select(depth + 1 >= self.rr_depth, q, 1.0)

    def survivals(self, beta, eta, depth, pre, q, classic, inv_p, Q, active, scale=1.0,
                  raw=None, scales=(1.0,)):
        """The running products 1/P (the pass's survivals) and Q (the alternative's inverse
        survivals) of the estimate of an alternative roulette (see the module docstring), past
        the decision at a vertex reached with ``beta`` (the pass's weights), ``eta``,
        ``depth``, whose continuation takes the BSDF sample ``pre``: the pass survives with the
        learned ``q``, or where the vertex is ``classic`` with the rule applied to its own
        throughput (inside :meth:`Wavefront.continuation`).  The alternative's throughput is
        beta Q / P ``scale`` (``scale``: the pass's own weight that the alternative does not
        apply, the first hit's 1/n of a split pass's first copy); the alternative is the
        throughput rule, or with ``raw`` (the vertex's unclamped roulette factor,
        :meth:`factor`) the learned roulette, which applies the rule at its own rule vertices
        (nothing learned, no smooth lobe: ``raw`` below zero).  ``Q`` is a list, one per
        alternative; ``scales``: with ``raw``, each alternative's factors scaled by its scale
        (:meth:`compare`)."""
        q_pass = dr.select(classic, self.classic_survival(beta, eta, depth, pre), q)
        on = active & (q_pass > 0)
        Q_out = []
        for Q_s, s in zip(Q, scales):
            rho = Q_s * inv_p * scale
            r = self.classic_survival(beta * rho, eta, depth, pre)
            if raw is not None:
                r = dr.select(raw < 0.0, r, dr.clip(s * raw * rho, self.rr_min, 1.0))
            # (r is zero only where the BSDF sample's weight is: the path ends in both)
            Q_out.append(dr.select(on & (r > 0), Q_s * dr.rcp(r), Q_s))
        return dr.select(on, inv_p * q_pass, inv_p), Q_out

    # ---- between passes ------------------------------------------------------------------
    def learn(self, spp: int, seconds: float = 0.0):
        """Factors for the next pass from the statistics so far (see the module docstring);
        ``seconds``: the pass's wall time (the efficiency of its mode, ``next_mode``)."""
        s1 = host(self.pass_s1)
        s2 = host(self.pass_s2)
        cost = self.pass_cost / max(s1.size * spp, 1)
        self.pix_s1 += s1
        self.pix_n += spp
        if not self.recording:
            return
        mean = self.pix_s1 / np.maximum(self.pix_n, 1)
        ip2 = relmse_denominator(mean)      # the relMSE's denominator
        # E[s2 / spp - mean^2] = sigma^2 (1 - 1/N), the mean taken over all N samples so far
        # (this pass's among them): half the variance after a first pass of 2 spp
        n_all = np.maximum(self.pix_n, 2)
        var = np.maximum(s2 / spp - mean ** 2, 0.0) * n_all / (n_all - 1)
        # (one sample per pixel so far says nothing of the variance: its own mean is the
        # sample, and float rounding read as variance made every factor huge; the next pass
        # stays classic and learns on)
        # (V read against the means that hold the pass's own samples: low in the first
        # passes, which keeps the young table's roulette mild; see pass_denominators)
        v_rel = float(np.mean(var / ip2)) if self.pix_n.min() >= 2 else 0.0
        k = cost / v_rel if v_rel > 0 else 0.0
        # the moments shrunk towards the parent level's: coarse cells towards the whole scene's,
        # fine cells towards their coarse cell's (see factors)
        # (on the cells with copies only: a few thousand of the fine grid's 65536)
        # (statistics: rows of the cells with copies; column 2 the copies)
        vis_c, st_c = self.coarse.visited(2)
        total = st_c.sum(axis=0)
        mom_c = np.zeros((self.coarse.size, 4))
        mom_c[vis_c] = self.moments(st_c, np.broadcast_to(
            total / max(total[2], 1e-30), (vis_c.size, 4)))
        vis_f, st_f = self.grid.visited(2)
        parent = host_view(self.parent)[vis_f]
        mom_f = self.moments(st_f, mom_c[parent])
        ok_any = False
        for grid, attr, st, vis, mom in ((self.grid, "f_var", st_f, vis_f, mom_f),
                                         (self.coarse, "f_var_coarse", st_c, vis_c,
                                          mom_c[vis_c])):
            f_m, f_v = np.full(grid.size, -1.0), np.full(grid.size, -1.0)
            f_m[vis], f_v[vis], ok = self.factors(st, mom, k, total[2])
            grid.set_table(f_m)
            setattr(self, attr, mi.Float(f_v.astype(np.float32)))
            grid.stats = grid.stats * DECAY
            # (evaluated now: a kernel scattering into it would evaluate it in mid-trace and
            # split itself in pieces that each run the loop)
            dr.eval(grid.stats)
            ok_any |= bool(ok.any())
        # (settled after a learned pass whose cells hold enough copies; the passes counted in
        # the current mode: the statistics recorded under another policy are not this one's)
        if self.mode in LEARNED_MODES:
            same = self.mode == self.learned_mode
            self.learned_passes = self.learned_passes + 1 if same else 1
            self.learned_mode = self.mode
        self.settled = bool(self.mode in LEARNED_MODES and ok_any and vis_f.size > 0 and
                            self.learned_passes >= SETTLED_PASSES and
                            median_copy_cell(st_f[:, 2]) >= SETTLED_COPIES)
        self.inv_pixel = mi.Float((1.0 / np.sqrt(ip2)).astype(np.float32))
        self.learned = ok_any
        self.v_rel, self.cost = v_rel, cost
        if self.pass_cost_c.size and self.pass_cost_c.min() > 0 and v_rel > 0:
            ip2 = self.pass_denominators(s1, spp)
            v_c = [self.relative_variances(s1, s2, host(s2c), spp, ip2) for s2c in
                   self.pass_s2c]
            self.compare(v_c[0][0], cost, [x[1] for x in v_c],
                         self.pass_cost_c / max(s1.size * spp, 1))
            # (not settled while an estimate is still to decide: a settled pass records
            # nothing and estimates nothing)
            if self.split_pending:
                self.settled = False
        # each mode's last pass, its efficiency measured against the current pixel means (the
        # same denominators for every mode: a pass measured against the noisier means of an
        # early pass would read less variance)
        # (the time per camera sample: the modes' costs per ray differ, e.g. a split pass's
        # replication; without a time, the cost model's units)
        per_sample = seconds / max(s1.size * spp, 1) if seconds > 0 else cost
        if self.mode in LEARNED_MODES:
            self.last_pass[self.mode] = (s2, spp, per_sample)
        for m, (s2_m, spp_m, t_m) in self.last_pass.items():
            v_m = float(np.mean(np.maximum(s2_m / spp_m - mean ** 2, 0.0) / ip2))
            self.measured[m] = 1.0 / (v_m * t_m) if v_m > 0 and t_m > 0 else 0.0
        self.mode = self.next_mode()

    def pass_denominators(self, s1, spp: int):
        """Per pixel the relMSE's denominator I_p^2 + 0.01 for the relative variances of a
        pass of ``spp`` samples per pixel (``s1``: its sums, already in ``pix_s1``) that
        :meth:`compare` weighs, from the pixel means of the earlier passes, which hold none of
        the pass's samples (those of all passes where there are none).  A denominator that
        holds the pass's samples is largest where they are, and divides their variance most
        where it is largest: a 2-spp pass's relative variance after a 2-spp classic pass read
        0.33 (ajar door, 96 px) and 0.89 (indirect room) against 8.6 and 7.9 with the earlier
        pass's means, and a 14-spp pass's after 52 spp still 0.6x.  The factors' V (the
        image's relative variance, :meth:`learn`) is still read against the means that hold
        the pass: with the earlier passes' means there too (the first pass's from its
        neighbouring pixels'), the young table's roulette was harsher, and the efficiency
        relative to ``nee_path`` at 32/128/512 spp (96 px, 4 repeats, run side by side, both
        with this comparison's variances then about the mean of all samples) was
        0.65/1.19/1.33x in the indirect room against 0.95/1.01/1.28x, the ajar door
        0.74/1.05/1.04x against 0.99/0.95/1.08x, the window 0.91/0.72/0.86x against
        0.87/0.85/1.01x, the heavy mesh 1.09/1.28/1.24x against 1.02/1.18/1.27x."""
        before = self.pix_n - spp
        if before.min() >= 1:
            return relmse_denominator((self.pix_s1 - s1) / before)
        return relmse_denominator(self.pix_s1 / np.maximum(self.pix_n, 1))

    def relative_variances(self, s1, s2, s2c, spp: int, ip2):
        """(v, v_c): the relative variances per camera sample of a learning pass of ``spp``
        samples per pixel (its per-pixel sums ``s1``, ``s2`` of the samples' luminance and its
        square) and of its alternative (``s2c``: the per-pixel sums of the alternative's
        second moment estimated on the same paths), for :meth:`compare`.  Per pixel the
        pass's variance about its own mean m, (s2 / spp - m^2) spp / (spp - 1), and the
        alternative's that plus (s2c - s2) / spp (the same mean: the difference is the second
        moments'; unclamped, as a clamp at zero would bias the two differently), each divided
        by ``ip2`` (:meth:`pass_denominators`, the earlier passes' means): weights that hold
        none of the pass's samples, and variances that hold none of the earlier ones'.  A
        denominator that holds the pass's own samples divides the pass's variance most where
        it is largest, and the alternative's (other weights on the same paths) less: the first
        roulette pass's estimate of its variance against the rule's read 2.7x (ajar door) and
        4.0x (the indirect room) where 16-spp passes with the same table measured 1.23x and
        2.41x (relMSE against the reference, 96 px); this way 1.13x and 2.17x from that pass,
        1.10-1.29x and 2.16-2.59x from the next ones.  (Variances about the mean of all the
        samples, which the weights' earlier samples are in, read 1.10x and 1.87x: on synthetic
        pixels of known ratio 2.2, 1.89 against 2.18 +- 0.07 this way.)  A pass of one sample
        per pixel takes the mean of all samples so far."""
        if spp >= 2:
            m = s1 / spp
            var = (s2 / spp - m ** 2) * spp / (spp - 1)
        else:
            n_all = np.maximum(self.pix_n, 2)
            mean = self.pix_s1 / np.maximum(self.pix_n, 1)
            var = (s2 / spp - mean ** 2) * n_all / (n_all - 1)
        var_c = var + (s2c - s2) / spp
        return float(np.mean(var / ip2)), float(np.mean(var_c / ip2))

    def compare(self, v: float, c: float, v_c: float, c_c: float):
        """The pass's efficiency relative to its alternative's (:attr:`alternative`), (v_c c_c)
        / (v c): its relative variance ``v`` and cost ``c`` per camera sample and the
        alternative's, ``v_c`` and ``c_c``, estimated on the same paths
        (:meth:`Wavefront.roulette_kernel`).  A roulette pass against the throughput rule
        (``gain``): below ``KERNEL_COST`` the learned roulette does not pay for its kernel, and
        the rest of the render runs ``plain``.  A classic pass (the rule) against the learned
        roulette at each of ``ROULETTE_SCALES`` (``v_c``, ``c_c`` one per scale): the largest
        gain (``young_gain``) sends the render plain at once where a roulette pass's estimate
        that large would (below ``KERNEL_COST``, and under ``auto`` below ``SPLIT_TRY``); else
        the first roulette pass still decides.  A split pass against the learned roulette
        (``split_gain``): below ``SPLIT_COST`` the splitting does not pay for its copies' time,
        and the render goes on with roulette only.  Policy ``auto`` waits, where the roulette
        gains ``SPLIT_TRY`` or more, for the split pass's estimate, and goes plain where
        neither the roulette nor the splitting (gain x split_gain / ``SPLIT_COST``) is worth
        ``KERNEL_COST`` over the rule."""
        v_c, c_c = np.atleast_1d(v_c), np.atleast_1d(c_c)
        if self.mode == "classic":
            # (the pass is the rule, its alternatives the learned roulette at each of
            # ``ROULETTE_SCALES``: the gain read the way a roulette pass reads it, the
            # largest over the scales)
            ratios = v * c / (np.maximum(v_c, 1e-30) * c_c)
            j = int(np.argmax(ratios))
            self.gain_scale = ROULETTE_SCALES[j] if ratios.size == len(ROULETTE_SCALES) \
                else 1.0
            self.young_gain = young = max(float(ratios[j]), 0.0)
            # (plain at once only where the first roulette pass's estimate, were it this
            # large, would send the render plain at once: else that pass decides)
            if young < KERNEL_COST and not (self.policy == "auto" and young >= SPLIT_TRY):
                self.gain, self.rule_cost = young, c
                self.go_plain()
            return
        else:
            ratio = max(float(v_c[0]), 0.0) * float(c_c[0]) / (max(v, 1e-30) * c)
            c_c = float(c_c[0])
        if self.mode == "split":
            self.split_gain = ratio
            if self.gain is None:       # (nothing estimated the rule: no fallback)
                return
            # (the better learned mode against the rule, each per its kernel's time)
            best = max(self.gain, self.gain * ratio / SPLIT_COST)
        else:
            self.gain = best = ratio
            self.rule_cost = c_c
            if self.split_pending:      # (the fallback waits for the split pass's estimate)
                return
        if best < KERNEL_COST:
            self.go_plain()

    def measure_bound(self, spp: int, trial: bool = False):
        """After a ``bound`` part of ``spp`` samples per pixel (its paths' costs counted by
        :class:`CostCounter` into ``pass_cost`` and ``pass_cost_first``, per camera sample of
        one copy): the bound on what learning could gain (:meth:`bound_gain`), then the plain
        kernel or a classic part.  Where the part carried the copy trial (``trial``; policy
        ``auto``) and the render goes plain with a trial to run (:meth:`go_plain`), the trial
        is measured (:meth:`measure_copies`): no plain part of its own, no second kernel traced
        (``small_light``, 96 px, calls of 2 spp: the trial's call of its own took 21 ms against
        ``nee_path``'s 10; carried by the bound part, it adds 4-6 ms to that part's 17).  Else
        its samples are the part's, their sums dropped."""
        n = max(self.shape[0] * self.shape[1] * spp, 1)
        self.copy_trial = False
        self.bound_gain(self.pass_cost / n, self.pass_cost_first / n)
        self.mode = "plain" if self.plain else "classic"
        if trial and self.copy_trial:
            self.measure_copies(spp)
        self.trial_block = None

    def bound_gain(self, c: float, c_first: float):
        """After a ``bound`` part (:attr:`bounding`: the throughput rule ends no path), an
        upper bound on the learned roulette's gain over the rule (:meth:`compare`): any
        roulette only adds variance there (E[X^2 / q] >= E[X^2]), so the gain is at most the
        saving in cost, ``c`` / ``c_first``, ``c`` the part's (the rule's) cost per camera
        sample and ``c_first`` its cost had every path ended at its first hit after the hit's
        light samples.  Below ``KERNEL_COST`` / (1 - ``BOUND_LOSS``) no learning part is run to
        estimate the gain, and the render goes plain (max_depth 4, 96 px: ``sharp_glossy``'s
        bound 1.297, the roulette pass estimated 1.000; Veach's MIS scene, ``small_light``,
        ``many_lights``: bounds 1.31-1.34, estimated 1.000-1.03).  (Policy ``auto``'s split
        trial, where the roulette gains ``SPLIT_TRY`` or more, is not run either: the first
        hit's splitting is then the plain kernel's copies, chosen by the copy trial.  A
        tighter bound from the continuations' second moments is not to be had: where A = v -
        sum e_t^2 is negative, as in ``small_light``, (A + sum e_t^2 / q_t)(B + sum q_t c_t)
        has no Cauchy-Schwarz bound, and continuations that add nothing are ended at no cost
        in variance.)"""
        if not (c > 0 and c_first > 0):
            return
        self.gain_bound = c / c_first
        if self.gain_bound * (1.0 - BOUND_LOSS) < KERNEL_COST:
            self.rule_cost = c
            self.go_plain()

    def go_plain(self):
        """The learned modes found not to pay for their kernel: the rest of the render runs
        ``plain``.  Policy ``auto``: its first plain pass the copy trial, except where copies
        could not gain ``COPY_GAIN`` even if they held all of the variance but the share
        ``TRIAL_V0`` (a camera sample's cost small against its copy's)."""
        self.plain = True
        if self.policy == "auto" and self.rule_cost is not None and copies_for(
                CAMERA_COST, self.rule_cost - CAMERA_COST, TRIAL_V0, 1.0, self.split_max) > 1:
            self.copy_trial = True

    def next_mode(self) -> str:
        """The mode of the next pass (see ``MODES``).  Nothing learned: ``classic``.  Policy
        ``never`` / ``always``: ``roulette`` / ``split``.  ``measured``: each learned mode once
        (roulette, then split), then the one of higher measured efficiency (its estimate
        renewed by every learning pass it runs).  ``auto``: roulette until a roulette pass
        estimated the rule, then split where that gain is ``SPLIT_TRY`` or more, then split
        while the split passes estimate a gain of ``SPLIT_COST`` or more over the roulette,
        else roulette (plain, :meth:`compare`, before any of these, or after the classic
        pass that estimates the learned roulette)."""
        if self.forced is not None:
            return "roulette" if self.policy == "never" else "split"
        if self.plain:
            return "plain"
        if not self.learned or not self.mature:
            return "classic"
        if self.policy == "auto":
            # (the rule estimated first, then splitting tried where the roulette gained
            # enough, and kept while it pays)
            if self.gain is None:
                return "roulette"
            if self.split_gain is None:
                return "split" if self.split_pending else "roulette"
            return "split" if self.split_gain >= SPLIT_COST else "roulette"
        if self.policy != "measured":
            return "split" if self.policy == "always" else "roulette"
        for m in LEARNED_MODES:
            if m not in self.measured:
                return m
        return max(LEARNED_MODES, key=lambda m: self.measured[m])

    @staticmethod
    def trial_samples(spp: int) -> int:
        """The copy trial's samples per pixel in a pass of ``spp`` (at least 2):
        ``TRIAL_SAMPLES``, or all of a shorter pass."""
        return min(spp, TRIAL_SAMPLES)

    def measure_copies(self, spp: int):
        """After the copy trial's plain pass of ``spp`` samples per pixel (:attr:`copy_trial`;
        the first :meth:`trial_samples` of every pixel took ``trial_copies`` copies, and only
        they are in ``trial_block``): the variance of their pixels, and the share of it that
        the copies would average, in the image as the relMSE sees it (the film's filter pools
        neighbouring pixels' samples, which averages the copies' noise, independent between
        samples, more than the shared part, which varies over the pixel footprint: in
        ``small_light``, with Mitsuba's Gaussian filter, 2 copies lower the box-filtered
        pixels' variance 1.7x and the image's 1.2x); and from them the plain kernel's copies
        from then on (:meth:`best_copies`).  A pixel's variance from the difference of its
        even and odd samples' filtered means F_e, F_o (each the filter's sum over its own
        samples, of weights w_e, w_o): (F_e - F_o)^2 w_e w_o / (w_e + w_o)^2; the copies' share
        E[D^2], D the filtered mean of the half differences of the first two copies, whose
        variance given the camera samples is the image's.  Both relative (divided by I_p^2 +
        0.01), averaged over the pixels.  ``copy_var`` = (the rest, V_0; one copy's share,
        V_1): with k copies the pass's variance would be V_0 + V_1 / k."""
        block = self.trial_block
        self.trial_block = None
        if self.trial_copies >= 2 and spp >= 2:
            t = host(block.tensor()).astype(np.float64)
            t = t.reshape(t.shape[0], -1, 5)
            w_e, w_o = t[..., 1], t[..., 3]
            ok = (w_e > 0) & (w_o > 0)
            w = np.where(ok, w_e + w_o, 1.0)
            f_e, f_o = t[..., 0] / np.where(ok, w_e, 1.0), t[..., 2] / np.where(ok, w_o, 1.0)
            var = (f_e - f_o) ** 2 * w_e * w_o / w ** 2
            d2 = (t[..., 4] / w) ** 2
            # (relative to the filtered pixels, as the relMSE's reference is: next to a bright
            # pixel, a dark one's filtered value holds its neighbour's light and its variance)
            ip2 = relmse_denominator((t[..., 0] + t[..., 2]) / w)
            if ok.any():
                x, y = np.where(ok, var / ip2, 0.0), np.where(ok, d2 / ip2, 0.0)
                n = float(ok.sum())
                v1 = 2.0 * float(y.sum()) / n     # (D: the mean of two copies)
                self.copy_var = (float(x.sum()) / n - v1 / self.trial_copies, v1)
                self.copy_tiles = (tile_sums(x, COPY_TILE), tile_sums(y, COPY_TILE))
        self.copy_trial = False
        self.copies = self.best_copies()

    def best_copies(self) -> int:
        """The plain kernel's copies per camera sample after the copy trial (:func:`copies_lower`
        with its tiles' sums, and the costs of the cost model: ``CAMERA_COST`` the camera
        sample's, the rest of the throughput rule's cost the copy's; 1 before the trial)."""
        if self.copy_tiles is None or self.rule_cost is None:
            return 1
        return copies_lower(CAMERA_COST, self.rule_cost - CAMERA_COST, *self.copy_tiles,
                            self.trial_copies, self.split_max)

    @property
    def split_pending(self) -> bool:
        """Policy ``auto``: splitting not tried yet, and to be tried (the last roulette pass
        estimated a gain of ``SPLIT_TRY`` or more over the throughput rule)."""
        return (self.policy == "auto" and self.split_gain is None and self.gain is not None
                and self.gain >= SPLIT_TRY)

    @property
    def mature(self) -> bool:
        """Whether the learned modes may run: under the policies whose first roulette pass's
        estimate decides (``never``, ``auto``), once the pixels hold ``MATURE_SPP`` samples
        (classic passes until then, the ones with a table learned estimating the learned
        roulette, :attr:`alternative`); under the others at once."""
        return self.policy not in ("never", "auto") or self.pix_n.min() >= MATURE_SPP

    @property
    def alternative(self):
        """What a learning pass of the current mode estimates on its own paths besides itself
        (:meth:`compare`): under the ``never`` and ``auto`` policies a classic pass with a
        table learned, before the pixels hold ``MATURE_SPP`` samples (:attr:`mature`), the
        learned roulette with that table at each of ``ROULETTE_SCALES`` (``"learned"``), and a
        roulette pass the throughput rule (``"rule"``); a split pass of the ``auto`` policy
        the learned roulette (``"roulette"``); else None."""
        if self.mode == "classic" and self.policy in ("never", "auto") and self.learned \
                and self.forced is None and not self.mature:
            return "learned"
        if self.mode == "roulette" and self.policy in ("never", "auto"):
            return "rule"
        if self.mode == "split" and self.policy == "auto":
            return "roulette"
        return None

    @staticmethod
    def moments(st: np.ndarray, prior):
        """Per cell (E[L_r^2], E[L_r], copies, cost per copy), each moment shrunk towards the
        ``prior``'s (rows of the same layout) with the weight of ``PRIOR_VISITS`` copies:
        (sum + PRIOR_VISITS prior) / (count + PRIOR_VISITS)."""
        cnt = st[:, 2]
        sums = st[:, (0, 1, 3)]
        pri = np.asarray(prior)[:, (0, 1, 3)]
        est = (sums + PRIOR_VISITS * pri) / (cnt + PRIOR_VISITS)[:, None]
        return np.column_stack([est[:, :2], cnt, est[:, 2]])

    @staticmethod
    def factors(st: np.ndarray, mom: np.ndarray, k: float, total: float):
        """Per cell sqrt(M k / c) and sqrt(Var k / c) from its shrunk moments ``mom``
        (:meth:`moments`; -1 where the cell has no copies, or the scene fewer than
        MIN_VISITS), k = C / V; and where they are defined."""
        ok = (st[:, 2] > 0) & (total >= MIN_VISITS) & (k > 0)
        c = np.maximum(np.where(ok, mom[:, 3], 1.0), 1e-6)
        m2 = np.where(ok, mom[:, 0], 0.0)
        mu = np.where(ok, mom[:, 1], 0.0)
        v = np.maximum(m2 - mu ** 2, 0.0)
        f_m = np.where(ok, RR_MARGIN * np.sqrt(m2 * k / c), -1.0)
        f_v = np.where(ok, np.sqrt(v * k / c), -1.0)
        return f_m, f_v, ok


def copies_for(a: float, b: float, v0: float, v1: float, k_max: int) -> int:
    """The copies k of the first hit per camera sample of highest predicted efficiency, 1 /
    ((V_0 + V_1 / k) (a + b k)), 1 <= k <= ``k_max``: V_1 (``v1``) a copy's relative variance
    per camera sample (the spread of the copies of one camera sample), V_0 (``v0``) the rest
    (the camera ray's footprint and first hit, which the copies share); ``a`` the cost of a
    camera sample before its copies, ``b`` a copy's.  k >= 2 only where it gains ``COPY_GAIN``
    over one copy."""
    # (its variances as two like tiles of a two-copy trial, E[x] = V_0 + V_1 / 2, E[y] =
    # V_1 / 2: no spread, so copies_lower's bound is the estimate)
    v0, v1 = max(v0, 0.0), max(v1, 0.0)
    x, y = v0 + v1 / 2.0, v1 / 2.0
    return copies_lower(a, b, [x, x], [y, y], 2, k_max, z=0.0)


def copies_lower(a: float, b: float, X, Y, k_trial: int, k_max: int, z: float = None) -> int:
    """The copies k of the first hit per camera sample whose predicted efficiency gain over
    one copy (:func:`copies_for`'s) has the highest lower confidence bound, ``z`` (default
    ``COPY_Z``) standard errors below it; k >= 2 only where that bound is ``COPY_GAIN`` or
    more.  ``X``, ``Y``: per tile of the copy trial's pixels (``k_trial`` copies), the sums of
    their relative variance x and of the copies' share D^2, y (E[x] = V_0 + V_1 / k_trial,
    E[y] = V_1 / 2): k copies' variance is then estimated by sum(x + 2 y (1/k - 1/k_trial)),
    and its ratio to one copy's, a ratio of sums over the tiles, has the standard error
    sqrt(n / (n - 1) sum_t (u_t - R w_t)^2) / sum_t w_t (the ratio estimator's, the tiles
    taken as independent)."""
    z = COPY_Z if z is None else float(z)
    X, Y = np.asarray(X, np.float64).ravel(), np.asarray(Y, np.float64).ravel()
    n = X.size
    if not (a > 0 and b > 0) or n < 2:
        return 1
    u = X + 2.0 * Y * (1.0 - 1.0 / k_trial)
    best, best_gain = 1, 1.0
    for k in range(2, max(int(k_max), 1) + 1):
        w = X + 2.0 * Y * (1.0 / k - 1.0 / k_trial)
        W = w.sum()
        if not W > 0:       # (k copies' variance read as none: no estimate to trust)
            continue
        R = u.sum() / W
        se = np.sqrt(n / (n - 1) * np.sum((u - R * w) ** 2)) / W
        gain = (R - z * se) * (a + b) / (a + b * k)
        if gain > best_gain:
            best, best_gain = k, gain
    return best if best_gain >= COPY_GAIN else 1


def trial_stride(h: int, w: int, box: bool = True) -> int:
    """The stride of the copy trial's pixel lattice in an h x w layout (``TRIAL_PIXELS``;
    ``box``: whether the film's filter is a box, else 1)."""
    return max(1, int(np.sqrt(h * w / max(TRIAL_PIXELS, 1)))) if box else 1


def trial_pixels(h: int, w: int, box: bool = True):
    """The copy trial's pixels of an h x w layout (row-major indices: every
    :func:`trial_stride`-th pixel of every such row, from the first), and the others, each in
    order, as ``UInt32`` arrays, and the count of the first; (None, None, h w) where the trial
    takes every pixel."""
    s = trial_stride(h, w, box)
    if s == 1:
        return None, None, h * w
    on = np.zeros((h, w), bool)
    on[::s, ::s] = True
    idx = np.arange(h * w, dtype=np.uint32)
    return mi.UInt32(idx[on.ravel()]), mi.UInt32(idx[~on.ravel()]), int(on.sum())


def tile_sums(x: np.ndarray, size: int) -> np.ndarray:
    """Sums of the (h, w) image ``x`` over tiles of ``size`` pixels a side (the last row and
    column of tiles as large as is left)."""
    h, w = x.shape
    rows = np.add.reduceat(x, np.arange(0, h, size), axis=0)
    return np.add.reduceat(rows, np.arange(0, w, size), axis=1).ravel()


def median_copy_cell(copies) -> float:
    """The copies held by the cell of the median copy (the cells' counts ``copies`` weighted by
    themselves): half the copies are in cells that hold at least this many.  What a vertex's
    factor is learned from, taken where the vertices are: the median over the cells counts
    every rarely visited cell as much as a busy one."""
    c = np.sort(np.asarray(copies, np.float64).ravel())
    if c.size == 0 or c[-1] <= 0:
        return 0.0
    return float(c[np.searchsorted(np.cumsum(c), 0.5 * c.sum())])


# ---- the records of the megakernel (Wavefront.roulette_kernel): one tuple per vertex depth j,
# (fine cell, coarse cell, luminance of the surviving copy's beta, sum of the luminance its
# continuation added, sum of its cost); outside the kernel's function because Dr.Jit's syntax
# rewriting does not take comprehensions with tuple targets
def records_add(recs, depth, lc, k, first=0):
    """Add a continuation's contribution ``lc`` and cost ``k`` to the records made before it
    (record j, of the vertex at depth first + j, where the continuation's new depth exceeds
    that)."""
    out = []
    for j, (a, b, bl, S, R) in enumerate(recs):
        after = depth > first + j
        out.append((a, b, bl, S + dr.select(after, lc, 0.0), R + dr.select(after, k, 0.0)))
    return out


def records_start(recs, depth, cell, blum, first=0):
    """Make the record of the vertex at ``depth`` (its cells and its copy's throughput
    luminance; zero where the copy was rouletted)."""
    out = []
    for j, (a, b, bl, S, R) in enumerate(recs):
        here = depth == first + j
        out.append((dr.select(here, cell[0], a), dr.select(here, cell[1], b),
                    dr.select(here, blum, bl), S, R))
    return out


def records_flush(ears, recs, mode=DIRECT):
    """The records' L_r = S / beta, its square, the count and the cost to both grids (and the
    fine cell's coarse cell)."""
    for a, b, bl, S, R in recs:
        L_r = safe_div(S, bl)
        record_sums(ears, (a, b), [L_r * L_r, L_r, mi.Float(1.0), R], bl > 0, mode)


def record_sums(ears, cell, vals, active, mode=DIRECT):
    """Statistics (sums of L_r^2, L_r, copies, cost) to the fine and the coarse cell ``cell``,
    and the coarse cell as the fine one's parent (``mode``: the scatters' reduce mode)."""
    ears.grid.add(cell[0], vals, active, mode=mode)
    ears.coarse.add(cell[1], vals, active, mode=mode)
    # (an atomic max: commutative, so no scatter has to wait for another, which a plain
    # scatter into the same array would, splitting the kernel: any coarse cell a fine cell
    # lies in will do)
    dr.scatter_reduce(dr.ReduceOp.Max, ears.parent, cell[1], cell[0], active, mode=mode)


def predict_start(c0, k0, n: int):
    """An alternative's estimate (see :func:`predict_add`) at its start, for each of ``n``
    alternatives (lists: Y, S, K): the first contribution ``c0``, of cost ``k0``."""
    return [c0 * c0 for _ in range(n)], [mi.Float(c0) for _ in range(n)], \
        [mi.Float(k0) for _ in range(n)]


def predict_add(Y, S, K, lc, k, inv_p, Q, on):
    """An alternative's estimate (see the module docstring, :meth:`EARS.survivals`) past a
    contribution ``lc`` (the luminance the pass adds, its weights in) of cost ``k``, where
    ``on``: its second moment Y, the running S and its cost K."""
    bare = lc * inv_p
    out = [], [], []
    for Y_s, S_s, K_s, Q_s in zip(Y, S, K, Q):
        out[0].append(Y_s + dr.select(on, lc * (bare * Q_s + 2.0 * S_s), 0.0))
        out[1].append(S_s + dr.select(on, bare * Q_s, 0.0))
        out[2].append(K_s + dr.select(on, k * safe_div(1.0, inv_p * Q_s), 0.0))
    return out


def split_weight(n, m):
    """Weight of each of the m = floor(n + u) copies made with factor n: 1/n where n < 1
    (roulette: m is 0 or 1, E[m / n] = 1), 1/m where n >= 1 (there m >= 1, so the copies' mean
    is unbiased for any count, and free of the noise of a random count divided by n, Var(m)
    mu^2 / n^2, which where the first hit's light samples are large and steady outweighed what
    the copies average: ``split_policy=always`` on ``small_light`` and ``cornell_box``, relMSE
    1.16-1.25x and 1.12-1.14x lower with 1/m at 32 and 128 spp, 96 px; ``veach_mis`` and the
    indirect room alike).  The cost: E[1/m] - 1/n of the copies' variance (4 % at n = 2.5)."""
    return dr.select(n < 1.0, copy_weight(n), safe_div(1.0, mi.Float(m)))


def copy_weight(n):
    """Weight of each copy of a path continued with factor n (floor(n + u) copies): 1/n, so that
    E[copies x weight] = 1 for any n > 0."""
    return safe_div(1.0, n)


def random_factors(lo: float, hi: float):
    """A ``forced`` rule for tests: n uniform in [lo, hi] at every vertex, independently."""
    def rule(sampler, active):
        return lo + (hi - lo) * sampler.next_1d(active)
    return rule


def fixed_factor(n: float):
    """A ``forced`` rule for tests: the same n at every vertex (e.g. ``split_max``)."""
    def rule(sampler, active):
        return dr.full(mi.Float, n, dr.width(active))
    return rule


class CostCounter:
    """The learner interface of :meth:`VertexEstimator.path` that learns nothing (the path
    and its estimate unchanged) and counts what the path costs in the cost model's units, for a
    ``bound`` part (:meth:`EARS.bound_gain`): per vertex ``shadow`` (``SHADOW_COST`` per light
    sample) where its BSDF has a smooth lobe, and its continuation ray (1) where the path goes
    on, as the megakernel counts them (:meth:`Wavefront.light`, :meth:`Wavefront.continuation`:
    no ray where the roulette, or a BSDF sample of zero weight, ended the path); ``sums``
    (evaluated with the pass) holds their sum over the paths and the sum of the first
    vertices' shadow costs.  The camera rays' cost is the caller's."""

    def __init__(self, shadow: float):
        self.shadow = float(shadow)
        self.sums = dr.zeros(mi.Float, 2)

    def light_probability(self, si, sampler, active):
        # (no probability: every vertex its light samples; what the vertex's shadow rays cost)
        smooth = active & mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Smooth)
        return None, dr.select(smooth, self.shadow, 0.0)

    def path_start(self, like):
        # (the path's cost so far, and its first vertex's shadow cost: -1 before it)
        return widen(mi.Float(0.0), like.x), widen(mi.Float(-1.0), like.x)

    def path_vertex(self, track, shadow, p, active):
        cost, first = track
        first = dr.select(active & (first < 0.0), shadow, first)
        return cost + dr.select(active, shadow, 0.0), first

    def path_ray(self, track, active):
        cost, first = track
        return cost + dr.select(active, 1.0, 0.0), first

    def record_light(self, *args):
        pass

    def record_pair(self, *args):
        pass

    def record_hit(self, *args):
        pass

    def record_path(self, track, L):
        cost, first = track
        zero = mi.UInt32(0)
        dr.scatter_reduce(dr.ReduceOp.Add, self.sums, cost, zero, mode=FLUSH)
        dr.scatter_reduce(dr.ReduceOp.Add, self.sums, dr.maximum(first, 0.0), zero + 1,
                          mode=FLUSH)


class Wavefront:
    """One pass of path tracing with EARS path replication, for the integrator ``integ``
    (``nee_path``: its ``vertex`` estimator, ``camera_hit``, ``max_depth``)."""

    def __init__(self, integ, ears: EARS, max_lanes: int):
        self.integ, self.ears, self.max_lanes = integ, ears, int(max_lanes)
        split = ears.mode == "split"
        #: splitting at the first hit only: its copies run in the megakernel, one after another
        #: in the lane (:meth:`roulette_kernel`); splitting deeper replicates lanes
        self.copies = split and ears.split_depth == 1
        self.replicated = ears.split_depth if split and not self.copies else 0
        self.stats = dict(camera_rays=0, continuation_rays=0, shadow_rays=0, camera_samples=0,
                          max_lanes=0, bounces=0, batches=0, capped_bounces=0)
        #: whether the pass ran the copy trial (:meth:`render`)
        self.trial = False
        #: the megakernel's sums of work and rays over the pass's batches (kernel_batch)
        self._totals = None
        #: a roulette pass's estimate of the throughput rule's cost, summed (kernel_batch)
        self._pred = None

    # ---- camera samples ----------------------------------------------------------------------
    @staticmethod
    def camera_rays(sensor, sampler, idx, spp: int):
        """Camera rays of the samples ``idx`` (sample j of pixel j // spp), as Mitsuba's
        ``sample_rays``: (ray, weight, splatting position, pixel index)."""
        film = sensor.film()
        width = film_shape(film)[1]
        pixel = idx // dr.opaque(mi.UInt32, spp)
        pos = mi.Vector2i()
        pos.y = mi.Int32(pixel // width)
        pos.x = mi.Int32(pixel) - pos.y * width
        if film.sample_border():
            pos -= film.rfilter().border_size()
        pos += mi.Vector2i(film.crop_offset())
        pos_f = mi.Vector2f(pos) + sampler.next_2d()
        scale = dr.rcp(mi.ScalarVector2f(film.crop_size()))
        offset = -mi.ScalarVector2f(film.crop_offset()) * scale
        aperture = sampler.next_2d() if sensor.needs_aperture_sample() else mi.Vector2f(0.0)
        time = sensor.shutter_open()
        if sensor.shutter_open_time() > 0:
            time += sampler.next_1d() * sensor.shutter_open_time()
        wav = sampler.next_1d() if mi.is_spectral else mi.Float(0.0)
        ray, weight = sensor.sample_ray(time, wav, dr.fma(pos_f, scale, offset), aperture)
        n = dr.width(idx)
        if dr.width(ray) != n:      # a sensor whose ray ignores the position (radiancemeter)
            ray = dr.gather(mi.Ray3f, ray, dr.zeros(mi.UInt32, n))
        if dr.width(weight) != n:
            weight = dr.gather(mi.Spectrum, weight, dr.zeros(mi.UInt32, n))
        splat = mi.Vector2f(pos) if film.rfilter().is_box_filter() else pos_f
        return ray, weight, splat, pixel

    # ---- the pass ------------------------------------------------------------------------
    def render(self, scene, sensor, seed: int, spp: int, block=None):
        """Render ``spp`` samples per pixel into ``block`` (default: a new one of the film's);
        returns the block.  In the ``plain`` mode (a part of a call after the learned roulette
        was found not to pay, :meth:`EARS.part`) the integrator's own kernel
        (``sample_copies``: the throughput rule, ``EARS.copies`` copies of the first hit, no
        records, its rays not counted; in the copy trial its pixels' sums kept)."""
        from mitsuba.ad.integrators.common import ADIntegrator
        film = sensor.film()
        h, w = film_shape(film)
        self.ears.film((h, w), sensor_view(sensor))
        total = w * h * spp
        kernel = self.replicated == 0
        plain = self.ears.mode in ("plain", "bound")
        # (a bound part: the plain kernel, its paths' costs counted)
        counter = None
        if self.ears.mode == "bound":
            counter = CostCounter(self.shadow_cost(self.integ.prepare(scene)))
        # (a plain pass of the copy trial: what its trial samples measure splatted with the
        # film's filter, EARS.measure_copies; the sample border left out)
        trial = self.trial = plain and bool(self.ears.copy_trial) and spp >= 2
        if trial:
            # (not coalesced: the trial's neighbouring lanes are neighbouring pixels, whose
            # footprints differ; small_light, 96 px, 2 spp: 1.5 ms less of a 10 ms kernel)
            self.ears.trial_block = mi.ImageBlock(film.crop_size(), film.crop_offset(), 5,
                                                  film.rfilter(), coalesce=False)
            n_trial = self.ears.trial_samples(spp)
            lattice = trial_pixels(h, w, film.rfilter().is_box_filter())
        demand = min(max(self.ears.lane_demand, 2.0), 2.0 * self.ears.split_max + 1.0)
        batch = self.max_lanes if kernel else max(1, int(self.max_lanes / (1.1 * demand)))
        self._demand = 0.0
        if block is None:
            block = film.create_block()
        sampler = mi.load_dict({"type": "independent"})
        for b0 in range(0, total, batch):
            n = min(batch, total - b0)
            sampler.seed(dr.opaque(mi.UInt32, seed_mix(seed, b0, 0xCA)), n)
            # (the offset opaque: a literal would compile the kernel again for every batch)
            idx = dr.arange(mi.UInt32, n) + dr.opaque(mi.UInt32, b0)
            if trial:
                idx, in_trial = self.trial_layout(idx, w * h, spp, n_trial, *lattice[:2])
            ray, weight, pos, pixel = self.camera_rays(sensor, sampler, idx, spp)
            if plain:       # (the integrator's own kernel, the throughput rule)
                copies = self.ears.copies
                if trial:
                    copies = dr.select(in_trial, self.ears.trial_copies, mi.UInt32(1))
                L, valid, half = self.integ.sample_copies(scene, sampler, ray, copies,
                                                          learner=counter)
            elif kernel:
                L, valid = self.kernel_batch(scene, sampler, ray, pixel)
            else:
                L, valid = self.batch(scene, sampler, ray, pixel, seed, b0)
            ADIntegrator._splat_to_block(block, film, pos, value=L * weight, weight=1.0,
                                         alpha=dr.select(valid, mi.Float(1), mi.Float(0)),
                                         aovs=[], wavelengths=ray.wavelengths)
            self.stats["batches"] += 1
            # (the pixel in the units of the paths' throughputs, whose ratio to it is w: the
            # radiance along the camera ray, without the sensor's weight, which in spectral
            # variants is the wavelength sample's importance weight, tens of times the radiance)
            lum = luminance(L)
            if trial:       # (the pixel's even and odd trial samples apart, the copies' half)
                even = dr.select(((idx - pixel * spp) & 1) == 0, mi.Float(1.0), 0.0)
                odd = 1.0 - even
                self.ears.trial_block.put(pos, [lum * even, even, lum * odd, odd,
                                                mi.Float(0.0) if half is None else half],
                                          active=in_trial)
            if plain:   # (nothing learned from it, its rays not counted; the trial's sums kept)
                dr.eval(block.tensor(), self.ears.trial_block.tensor() if trial else None,
                        None if counter is None else counter.sums)
                continue
            dr.scatter_reduce(dr.ReduceOp.Add, self.ears.pass_s1, lum, pixel, mode=DIRECT)
            dr.scatter_reduce(dr.ReduceOp.Add, self.ears.pass_s2, lum * lum, pixel, mode=DIRECT)
            dr.eval(block.tensor(), self.ears.pass_s1, self.ears.pass_s2, self._totals,
                    self._pred, self.ears.pass_s2c)
            self.stats["camera_samples"] += n
        self.kernel_totals()
        if counter is not None:     # (the bound part's costs, the camera rays' included)
            rest, first = (float(x) for x in counter.sums)
            # (per copy: the trial's lanes ran trial_copies of the first hit's copies)
            share = 1.0
            if trial:
                share = total / (total + (self.ears.trial_copies - 1) * n_trial * lattice[2])
            self.ears.pass_cost = CAMERA_COST * total + rest * share
            self.ears.pass_cost_first = CAMERA_COST * total + first * share
        self.ears.lane_demand = self._demand
        return block

    @staticmethod
    def trial_layout(j, npix: int, spp: int, n_trial: int, pixels=None, others=None):
        """The copy trial's lanes ``j`` (:meth:`EARS.trial_samples`): the first ``n_trial``
        samples of each of the trial's ``pixels`` (:func:`trial_pixels`; default every pixel),
        sample-major (lane j < n_trial m, m pixels: sample j // m of the pixel j % m), then the
        rest of those pixels' samples, then every sample of the ``others``, each pixel-major: a
        SIMD packet of neighbouring lanes takes one count of copies, and waits for no other.
        Returns (the sample index as :meth:`camera_rays` takes it, whether the lane is a trial
        sample)."""
        m = npix if pixels is None else dr.width(pixels)
        head = dr.opaque(mi.UInt32, n_trial * m)
        M = dr.opaque(mi.UInt32, m)
        R = dr.opaque(mi.UInt32, max(spp - n_trial, 1))
        in_trial = j < head
        r = dr.select(in_trial, 0, j - head)
        # (the trial pixels' other samples: the first (spp - n_trial) m lanes after the head)
        tail = dr.opaque(mi.UInt32, (spp - n_trial) * m)
        mine = in_trial | (r < tail)
        k = dr.select(in_trial, j % M, r // R)
        s = dr.select(in_trial, j // M, dr.opaque(mi.UInt32, n_trial) + r % R)
        pix = k
        if pixels is not None:      # (a lattice: trial_pixels gives both lists or neither)
            o = dr.select(mine, 0, r - tail)
            S = dr.opaque(mi.UInt32, spp)
            k = dr.select(mine, k, 0)
            pix = dr.select(mine, dr.gather(mi.UInt32, pixels, k, mine),
                            dr.gather(mi.UInt32, others, o // S, ~mine))
            s = dr.select(mine, s, o % S)
        return pix * dr.opaque(mi.UInt32, spp) + s, in_trial

    def kernel_batch(self, scene, sampler, ray, pixel):
        """Every path of one batch in the megakernel (:meth:`roulette_kernel`): (L, valid)."""
        integ, ears = self.integ, self.ears
        sel = integ.prepare(scene)
        n_cam = dr.width(ray)
        learn = ears.recording
        L, valid, cost, traced, pred = self.roulette_kernel(
            scene, sel, sampler, ray, pixel, depth_limit(integ.max_depth), learn)
        if pred is not None:    # (the alternatives' second moments and costs, estimated)
            n_alt = len(pred[0])
            if len(ears.pass_s2c) != n_alt:
                ears.pass_s2c = [dr.zeros(mi.Float, dr.width(ears.pass_s1)) for _ in pred[0]]
                ears.pass_cost_c = np.zeros(n_alt)
            if self._pred is None:
                self._pred = dr.zeros(mi.Float, n_alt)
            for j, (Y, K) in enumerate(zip(*pred)):
                dr.scatter_reduce(dr.ReduceOp.Add, ears.pass_s2c[j], Y, pixel, mode=DIRECT)
                dr.scatter_reduce(dr.ReduceOp.Add, self._pred, K, mi.UInt32(j), mode=FLUSH)
            ears.pass_cost_c += CAMERA_COST * dr.width(ray)
        # the batch's work and rays summed in the same kernel (one expanded element per
        # thread), read once the pass is done (:meth:`kernel_totals`): no reduction kernel and
        # no host synchronisation per batch; the caller's splat goes with the loop too
        if self._totals is None:
            self._totals = (dr.zeros(mi.Float, 1), dr.zeros(mi.UInt32, 1))
        zero = mi.UInt32(0)
        dr.scatter_reduce(dr.ReduceOp.Add, self._totals[0], cost, zero, mode=FLUSH)
        dr.scatter_reduce(dr.ReduceOp.Add, self._totals[1], traced, zero, mode=FLUSH)
        self.stats["camera_rays"] += n_cam
        ears.pass_cost += CAMERA_COST * n_cam
        self._demand = max(self._demand, 1.0)
        return L, valid

    def kernel_totals(self):
        """The megakernel batches' work and rays into ``stats`` and the pass's cost."""
        if self._totals is None:
            return
        work, rays = float(self._totals[0][0]), int(self._totals[1][0])
        self._totals = None
        if self._pred is not None:
            self.ears.pass_cost_c += host(self._pred)
            self._pred = None
        self.stats["continuation_rays"] += rays
        self.stats["shadow_rays"] += int(round((work - rays) / SHADOW_COST))
        self.ears.pass_cost += work

    def batch(self, scene, sampler, ray, pixel, seed: int, b0: int):
        """Every path of one batch of camera samples: (L per camera sample, valid)."""
        integ, ears = self.integ, self.ears
        sel = integ.prepare(scene)
        n_cam = self._n_cam = dr.width(ray)
        self._scale = 1.0       # product of the cap's scalings so far in this batch
        limit = depth_limit(integ.max_depth)
        learn = ears.recording
        self._next = None
        self.L = dr.zeros(mi.Spectrum, n_cam)
        if integ.params.get("hide_emitters", False) or integ.max_depth == 0:
            si, L0 = integ.camera_hit(scene, ray, True)
        else:   # as camera_hit, keeping the preliminary intersection (a smaller state to copy)
            pi = scene.ray_intersect_preliminary(ray, coherent=True)
            si = pi.compute_surface_interaction(ray, mi.RayFlags.All)
            L0 = emitted(scene, si, True)
            self._next = (mi.Ray3f(ray), pi)
        valid = si.is_valid()
        alive = valid & (1 < limit)
        smooth = mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Smooth)
        sid = dr.arange(mi.UInt32, n_cam)
        beta = mi.Spectrum(1.0)
        eta = mi.Float(1.0)
        depth = mi.UInt32(0)
        u = sampler.next_1d()
        n, classic, cell = ears.factor(si, beta, eta, depth, pixel, sampler, alive,
                                       smooth=smooth)
        # the first hit's light samples: here, once, where n < 1 (roulette drops the
        # continuation alone), else in each copy (the first bounce, ``nee``)
        L_nee, k0, _, _ = self.light(scene, sel, sampler, si, alive & (n < 1.0), smooth)
        self.L += L0 + L_nee
        self.cost = dr.zeros(mi.Float, n_cam) + k0
        dr.eval(self.L, self.cost, valid, n, u, cell, classic,
                si if self._next is None else self._next)
        self.stats["camera_rays"] += n_cam
        recs = []
        self.traced = 0                         # continuation rays traced
        state = self.replicate(dict(si=si, beta=beta, eta=eta, depth=depth, sid=sid,
                                    pixel=pixel, hist=[], acc=[], classic=classic,
                                    nee=n >= 1.0),
                               n, u, cell, alive, recs,
                               learn)
        bounce = 0
        while state is not None:
            bounce += 1
            sampler.seed(dr.opaque(mi.UInt32, seed_mix(seed, b0, bounce)), state["width"])
            si, beta, eta, depth, alive, c, k, act, c0, k0 = self.vertex(scene, sel, sampler,
                                                                         state, limit)
            hist = state["hist"]
            # what this lane added to its camera sample, and since each of its records was made
            # (flushed to the camera sample and the records when the lane ends or splits: one
            # scatter per segment of a path, not an atomic add per bounce; the records are the
            # continuation's, without the first hit's light samples, c0)
            own = (state["own"][0] + c + c0, state["own"][1] + k + k0)
            lc = luminance(c)
            acc = [(a + lc, b + k) for a, b in state["acc"]]
            u = sampler.next_1d()
            n, classic, cell = ears.factor(si, beta, eta, depth, state["pixel"], sampler, alive)
            # one kernel: what the next wavefront gathers, and the scattered contributions
            dr.eval(self._next, beta, eta, depth, alive, n, u, cell, classic, own, acc, act)
            self.traced += int(dr.count(act)[0])
            state = self.replicate(dict(si=si, beta=beta, eta=eta, depth=depth,
                                        sid=state["sid"], pixel=state["pixel"], hist=hist,
                                        acc=acc, own=own, classic=classic),
                                   n, u, cell, alive, recs, learn and bounce < LEARN_DEPTH)
            if state is not None and bounce + 1 >= self.replicated:
                bounce += self.tail(scene, sel, sampler, state, limit, recs,
                                    seed_mix(seed, b0, bounce, 0x7A11), learn)
                state = None
        self.stats["bounces"] = max(self.stats["bounces"], bounce)
        # the cost of a bounce is 1 + SHADOW_COST per shadow ray: count them from it
        work = float(dr.sum(self.cost)[0])
        rays = self.traced
        self.stats["continuation_rays"] += rays
        self.stats["shadow_rays"] += int(round((work - rays) / SHADOW_COST))
        if learn:
            records_flush(ears, [(*r["cell"], r["blum"], r["S"], r["R"]) for r in recs])
        ears.pass_cost += work + CAMERA_COST * n_cam
        dr.eval(ears.grid.stats, ears.coarse.stats, ears.parent)
        return self.L, valid

    @record_once
    @dr.syntax
    def roulette_kernel(self, scene, sel, sampler, ray, pixel, limit, learn: bool):
        """Every path of a batch in one kernel (Mitsuba's megakernel).  At the first hit
        m = floor(n + u) copies of the continuation (n >= 1: and of the hit's light samples),
        each weighted 1/n (n < 1) or 1/m, run one after another in the lane, each restarting
        from the first hit with light samples and a BSDF sample of its own (n clamped to one
        in ``classic`` and ``roulette`` passes: roulette only); at the later vertices roulette
        with survival min(n, 1).  The records live in registers: the first hit's as
        sums over its copies (L_r, L_r^2, copies, cost), the deeper ones' for the first copy
        (a subset chosen before any outcome: the statistics stay fair); they go to the grids
        when the lane ends.  Returns (L, valid, cost, continuation rays) per camera sample."""
        ears = self.ears
        si, L = self.integ.camera_hit(scene, ray, True)
        valid = si.is_valid()
        alive = valid & (1 < limit)
        smooth = mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Smooth)
        beta, eta, depth = mi.Spectrum(1.0), mi.Float(1.0), mi.UInt32(0)
        n, classic, cell, raw = ears.factor(si, beta, eta, depth, pixel, sampler, alive,
                                            smooth=smooth, raw=True)
        # (without copies, a roulette or classic pass, the loop has no restart code, and
        # without learning no records: 2-3 % of the kernel's time on Veach's MIS scene)
        restarts = self.copies
        if not restarts:
            n = dr.minimum(n, 1.0)
        # a pass that learns may also estimate, on its own paths, the second moment and the
        # cost of an alternative (see the module docstring; EARS.alternative): per lane, Y
        # (its second moment), K (its cost), S, and the products 1/P of the pass's survivals
        # and Q of the alternative's inverse ones.  A roulette pass estimates the throughput
        # rule; a split pass the learned roulette, on each lane's first copy, whose weight
        # 1/n at the first hit (n > 1) the roulette does not apply (``scale``)
        alt = ears.alternative if learn else None
        predict = alt is not None
        versus = alt == "roulette"
        # (the learned roulette's factors, raw, where a split or a classic pass estimates it)
        use_raw = alt in ("roulette", "learned")
        scale = dr.maximum(n, 1.0) if versus else mi.Float(1.0)
        # (a classic pass estimates the learned roulette at each of the factors' scales, one
        # (Y, S, K, Q) each; the others one alternative)
        scales = ROULETTE_SCALES if alt == "learned" else (1.0,)
        # (as wide as the loop: unused, they stay in its state, see record_once)
        zero, one = widen(mi.Float(0.0), alive), widen(mi.Float(1.0), alive)
        inv_p = one
        Y, S, K = predict_start(zero, zero, len(scales))
        Q = predict_start(one, one, len(scales))[1]
        # the first hit's light samples: once where n < 1 (roulette drops the continuation
        # alone), else in each of its m = floor(n + u) copies, weighted 1/m like the rest of
        # it (the others take theirs when they restart)
        L_nee, cost, pre, smooth = self.light(scene, sel, sampler, si, alive, smooth)
        copies = mi.UInt32(dr.floor(n + sampler.next_1d()))
        w0 = split_weight(n, copies)
        if versus:      # (the roulette does not apply the copies' weight where n >= 1)
            scale = dr.select(n < 1.0, 1.0, mi.Float(copies))
        c_nee = dr.select(n < 1.0, 1.0, w0) * L_nee
        L += c_nee
        if predict:
            # (the alternative takes them once, after the first hit's decision where n >= 1,
            # where the pass's survival is one: counted before it, unscaled)
            c0 = luminance(L - c_nee) + luminance(c_nee) * scale
            Y, S, K = predict_start(c0, cost, len(scales))
            inv_p, Q = ears.survivals(beta, eta, depth, pre, dr.minimum(n, 1.0), classic, inv_p,
                                      Q, alive, raw=raw if use_raw else None, scales=scales)
        # floor(n + u) copies of the first hit's continuation, each weighted 1/n (n < 1:
        # roulette) or 1/m (split_weight), run one after another in the lane
        alive &= copies > 0
        left = dr.select(alive, copies - 1, 0)
        beta *= w0
        blum0 = dr.select(alive, luminance(beta), 0.0)
        si0, classic0, cell_first = mi.SurfaceInteraction3f(si), mi.Bool(classic), cell
        # record 0 (the first hit's cells): what the current copy added (S0, R0), and the sums
        # over its finished copies of L_r, L_r^2, copies, cost; records of deeper vertices:
        # (fine cell, coarse cell, luminance of the copy's beta, sum of its contributions, sum
        # of their cost), of the first copy only
        # (all as wide as the loop: in a pass without records or copies they stay unchanged in
        # its state, and a narrow one would have it recorded twice, see record_once)
        fz, uz = widen(mi.Float(0.0), alive), widen(mi.UInt32(0), alive)
        S0, R0 = fz, mi.Float(fz)
        t1, t2, tn, tR = mi.Float(fz), mi.Float(fz), mi.Float(fz), mi.Float(fz)
        recs = [(mi.UInt32(uz), mi.UInt32(uz), mi.Float(fz), mi.Float(fz), mi.Float(fz))
                for _ in range(LEARN_DEPTH - 1)]
        first = widen(mi.Bool(True), alive)
        stay = widen(mi.Bool(False), alive)
        active = mi.Bool(alive)
        # (counted per lane: an atomic counter shared by all lanes cost a tenth of the kernel)
        traced = mi.UInt32(0)
        # (read-only values stay out of the loop state: a narrow one, such as a literal
        # field of si0 or classic0 in a classic pass, would have the loop recorded twice)
        while dr.hint(active, label="ears kernel",
                      exclude=[limit, pixel, si0, classic0, w0, blum0, scale]):
            _, _, si_n, beta, eta, depth, alive, c, k, pre, act, smooth = self.continuation(
                scene, sel, sampler, si, beta, eta, depth, classic, limit, active, pre,
                stay=stay if restarts else None)
            L += c
            cost += k
            traced += dr.select(act, 1, 0)
            n, classic, cell, raw = ears.factor(si_n, beta, eta, depth, pixel, sampler, alive,
                                                False, smooth, raw=True)
            # (a copy that restarted takes the first hit's light samples: nothing decided)
            q = dr.select(stay, 1.0, dr.minimum(n, 1.0))
            if dr.hint(predict, mode="scalar"):
                # (a split pass: the first copy only)
                on = first if versus else mi.Bool(True)
                Y, S, K = predict_add(Y, S, K, luminance(c) * scale, k, inv_p, Q, on)
                inv_p2, Q2 = ears.survivals(beta, eta, depth, pre, q, classic, inv_p, Q,
                                            alive & on, scale, raw if use_raw else None,
                                            scales)
                inv_p = dr.select(on, inv_p2, inv_p)
                Q = dr.select(on, Q2, Q)
            alive &= sampler.next_1d() < q
            beta *= copy_weight(q)
            end = active & lnot(alive)
            if dr.hint(learn, mode="scalar"):
                lc = luminance(c)
                # (the statistics are the continuation's: a restarting copy's light samples at
                # the first hit left out)
                S0 += dr.select(stay, 0.0, lc)
                R0 += dr.select(stay, 0.0, k)
                d1 = dr.select(first, depth, 0)
                recs = records_add(recs, d1, lc, k, 1)
                blum = dr.select(alive, luminance(beta), 0.0)
                recs = records_start(recs, d1, cell, blum, 1)
                # a copy ends: its L_r to record 0's sums
                L_r = safe_div(S0, blum0)
                t1 += dr.select(end, L_r, 0.0)
                t2 += dr.select(end, L_r * L_r, 0.0)
                tn += dr.select(end, 1.0, 0.0)
                tR += dr.select(end, R0, 0.0)
                S0 = dr.select(end, 0.0, S0)
                R0 = dr.select(end, 0.0, R0)
                first &= lnot(end)
            si = si_n
            active = mi.Bool(alive)
            if dr.hint(restarts, mode="scalar"):
                # the next copy restarts at the first hit
                restart = end & (left > 0)
                left -= dr.select(restart, 1, 0)
                stay = restart
                si = dr.select(restart, si0, si_n)
                beta = dr.select(restart, mi.Spectrum(w0), beta)
                eta = dr.select(restart, 1.0, eta)
                depth = dr.select(restart, 0, depth)
                classic = dr.select(restart, classic0, classic)
                active = alive | restart
        if learn:
            records_flush(ears, recs, FLUSH)
            record_sums(ears, cell_first, [t2, t1, tn, tR], tn > 0, FLUSH)
        pred = None
        if predict:
            pred = (Y, K)
        return L, valid, cost, traced, pred

    @record_once
    @dr.syntax
    def tail(self, scene, sel, sampler, st, limit, recs, seed: int, learn: bool) -> int:
        """The paths left of a batch, finished in one kernel (a loop over the bounces)
        instead of a wavefront per bounce: the same vertex estimate, with roulette only (n
        clamped to 1: no more copies, so no more replication), survivors weighted 1/n.  What
        the lanes add goes to their records at the end.  The records of vertices deeper than
        the replicated ones but within ``LEARN_DEPTH`` are made here, in registers
        (:func:`records_start`), and go to the grids when the lane ends.  Returns the number
        of bounces."""
        ears = self.ears
        sampler.seed(dr.opaque(mi.UInt32, seed), st["width"])
        if "si" in st:
            si = mi.SurfaceInteraction3f(st["si"])
        else:
            si = st["pi"].compute_surface_interaction(mi.Ray3f(st["ray"]), mi.RayFlags.All, True)
        beta, eta, depth = mi.Spectrum(st["beta"]), mi.Float(st["eta"]), mi.UInt32(st["depth"])
        sid, pixel, classic = st["sid"], st["pixel"], mi.Bool(st["classic"])
        L_sum, cost_sum = mi.Spectrum(0.0), mi.Float(0.0)
        rays, traced = mi.UInt32(0), mi.UInt32(0)
        # register records for the depths replication did not reach (none if it did)
        first = len(recs)
        regs = [(mi.UInt32(0), mi.UInt32(0), mi.Float(0.0), mi.Float(0.0), mi.Float(0.0))
                for _ in range(LEARN_DEPTH - first if learn else 0)]
        active = mi.Bool(True)
        # the copies draw their first BSDF sample; then each lane continues with the one drawn
        # with its light samples
        fresh = dr.full(mi.Bool, True, st["width"])
        pre = (dr.zeros(mi.BSDFSample3f, st["width"]), dr.zeros(mi.Spectrum, st["width"]))
        while dr.hint(active, label="ears tail", exclude=[limit, sid, pixel]):
            _, _, si_n, beta, eta, depth, alive, c, k, pre, act, smooth = self.continuation(
                scene, sel, sampler, si, beta, eta, depth, classic, limit, active, pre, fresh)
            traced += dr.select(act, 1, 0)
            fresh &= lnot(active)
            L_sum += c
            cost_sum += k
            rays += 1
            n, classic, cell = ears.factor(si_n, beta, eta, depth, pixel, sampler, alive,
                                           smooth=smooth)
            q = dr.minimum(n, 1.0)
            alive &= sampler.next_1d() < q
            beta *= copy_weight(q)
            if dr.hint(len(regs) > 0, mode="scalar"):
                regs = records_add(regs, depth, luminance(c), k, first)
                regs = records_start(regs, depth, cell, dr.select(alive, luminance(beta), 0.0),
                                     first)
            si = si_n
            active = alive
        if len(regs) > 0:
            records_flush(ears, regs)
        dr.scatter_reduce(dr.ReduceOp.Add, self.L, st["own"][0] + L_sum, sid, mode=DIRECT)
        dr.scatter_reduce(dr.ReduceOp.Add, self.cost, st["own"][1] + cost_sum, sid, mode=DIRECT)
        lum_sum = luminance(L_sum)
        for r, hh, (a, b) in zip(recs, st["hist"], st["acc"]):
            dr.scatter_reduce(dr.ReduceOp.Add, r["S"], a + lum_sum, hh, mode=DIRECT)
            dr.scatter_reduce(dr.ReduceOp.Add, r["R"], b + cost_sum, hh, mode=DIRECT)
        longest, traced = dr.max(rays), dr.sum(traced)
        dr.eval(self.L, self.cost, longest, traced, [(r["S"], r["R"]) for r in recs])
        self.traced += int(traced[0])
        return int(longest[0])

    def light(self, scene, sel, sampler, si, active, smooth=None):
        """The light samples at a vertex (:meth:`VertexEstimator.direct`) and their cost, the
        BSDF sample drawn with them, and whether the BSDF has a smooth lobe (``smooth``, where
        the caller knows it): (L, cost, (BSDF sample, its weight), smooth).  The continuation
        from the vertex takes that sample (:meth:`continuation`'s ``pre``), except the copies
        of a split vertex past the first hit, which draw their own."""
        bsdf = si.bsdf()
        d = self.integ.vertex.direct(scene, sel, sampler, mi.BSDFContext(), si, bsdf, active)
        if smooth is None:
            smooth = mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        k = dr.select(active & smooth, self.shadow_cost(sel), 0.0)
        return dr.select(active, d.L, 0.0), k, (d.bs, d.weight), smooth

    def shadow_cost(self, sel) -> float:
        """The cost of a vertex's light samples where its BSDF has a smooth lobe (the kernels'
        and :class:`CostCounter`'s): ``SHADOW_COST`` per shadow ray, ``light_samples`` of them
        where the scene has lights to sample, else none."""
        return SHADOW_COST * self.integ.light_samples if sel.count > 0 else 0.0

    def continuation(self, scene, sel, sampler, si, beta, eta, depth, classic, limit, active,
                     pre=None, fresh=None, stay=None):
        """One copy's continuation from ``si``: a BSDF sample, its ray, the emission it finds
        (MIS-weighted against the light samples at ``si``), and the light samples at the vertex
        it reaches.  ``pre``: the BSDF sample drawn with the light samples at ``si``, used
        instead of a new one (except where ``fresh``: the copies of a split vertex past the
        first hit draw their own).  ``stay``: lanes that trace nothing and take the light
        samples at ``si`` itself (a copy of the first hit restarting there: its unit is the
        hit's light samples and continuation), their throughput and depth unchanged.  Returns
        (ray, pi, si_next, beta, eta, depth, alive, contribution, cost, the BSDF sample drawn at
        si_next, whether a ray was traced, whether the BSDF at si_next has a smooth lobe)."""
        vx = self.integ.vertex
        ctx = mi.BSDFContext()
        bsdf = si.bsdf()
        beta_in, eta_in, depth_in = beta, eta, depth
        if stay is not None:
            go, active = active, active & lnot(stay)
        if pre is None:
            bs, w = bsdf.sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active),
                                active)
        else:
            bs, w = pre
            if fresh is not None:
                bs_f, w_f = bsdf.sample(ctx, si, sampler.next_1d(active & fresh),
                                        sampler.next_2d(active & fresh), active & fresh)
                bs, w = dr.select(fresh, bs_f, bs), dr.select(fresh, w_f, w)
        beta = beta * w
        eta = eta * bs.eta
        depth = depth + 1
        beta, survives = self.ears.throughput_roulette(beta, eta, depth, classic, sampler,
                                                       active)
        act = active & survives & (bs.pdf > 0) & dr.any(mi.unpolarized_spectrum(beta) != 0)
        ray = si.spawn_ray(si.to_world(bs.wo))
        pi = scene.ray_intersect_preliminary(ray, coherent=False, active=act)
        si_n = pi.compute_surface_interaction(ray, mi.RayFlags.All, act)
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        L_w = vx.emission(scene, sel, si, si_n, [vx.n_b * bs.pdf], delta, act)
        c = dr.select(act, beta * L_w, 0.0)
        if stay is not None:
            here = go & stay
            si_n = dr.select(here, si, si_n)
            beta = dr.select(here, beta_in, beta)
            eta = dr.select(here, eta_in, eta)
            depth = dr.select(here, depth_in, depth)
            act_or_here = act | here
        else:
            act_or_here = act
        alive = act_or_here & si_n.is_valid() & (depth + 1 < limit)
        L_nee, k, nxt, smooth = self.light(scene, sel, sampler, si_n, alive)
        c += beta * L_nee
        return (ray, pi, si_n, beta, eta, depth, alive, c, dr.select(act, 1.0, 0.0) + k, nxt,
                act, smooth)

    def vertex(self, scene, sel, sampler, st, limit):
        """The kernel of one bounce over the live lanes (:meth:`continuation`): the next
        vertex, the contribution c, the cost k, and in the bounce from the first hit, where it
        split (``nee``), each copy's light samples there, c0 and their cost k0."""
        if "si" in st:
            si = st["si"]
        else:
            si = st["pi"].compute_surface_interaction(st["ray"], mi.RayFlags.All, True)
        pre, c0, k0 = None, mi.Spectrum(0.0), mi.Float(0.0)
        if "nee" in st:
            L0, k0, pre, _ = self.light(scene, sel, sampler, si, mi.Bool(st["nee"]))
            c0 = st["beta"] * L0
            fresh = lnot(st["nee"])
        ray, pi, si_n, beta, eta, depth, alive, c, k, _, act, _ = self.continuation(
            scene, sel, sampler, si, st["beta"], st["eta"], st["depth"], st["classic"], limit,
            mi.Bool(True), pre, None if pre is None else fresh)
        self._next = (ray, pi)
        return si_n, beta, eta, depth, alive, c, k, act, c0, k0

    def replicate(self, st, n, u, cell, alive, recs, record: bool):
        """The next wavefront: each lane with m = floor(s n + u) copies, each weighted 1/(s n)
        or, where s n >= 1, 1/m (:func:`split_weight`; s < 1 only where the lanes would pass
        the cap); None when no lane is left."""
        width = dr.width(n)
        n_sum = float(dr.sum(n)[0])
        live = int(dr.count(alive)[0]) if dr.width(dr.count(alive)) else 0
        # the demand as if no earlier bounce of the batch had been scaled by the cap
        self._demand = max(self._demand, (live + n_sum) / (self._n_cam * self._scale))
        s = 1.0
        if n_sum + live > self.max_lanes:
            s = max(self.max_lanes - live, 0) / n_sum
            self.stats["capped_bounces"] += 1
            self._scale *= max(s, 1e-6)
        ns = n * dr.opaque(mi.Float, s)
        counts = mi.UInt32(dr.floor(ns + u))
        counts = dr.select(alive & (ns > 0), counts, 0)
        # a lane that ends or splits hands what it added to its camera sample and its records
        # (see batch)
        flush = counts != 1
        if "own" in st:
            dr.scatter_reduce(dr.ReduceOp.Add, self.L, st["own"][0], st["sid"], flush,
                              mode=DIRECT)
            dr.scatter_reduce(dr.ReduceOp.Add, self.cost, st["own"][1], st["sid"], flush,
                              mode=DIRECT)
        for r, hh, (a, b) in zip(recs, st["hist"], st["acc"]):
            dr.scatter_reduce(dr.ReduceOp.Add, r["S"], a, hh, flush, mode=DIRECT)
            dr.scatter_reduce(dr.ReduceOp.Add, r["R"], b, hh, flush, mode=DIRECT)
        parents = dr.compress(counts > 0)
        if dr.width(parents) == 0:
            dr.eval(self.L, self.cost, [(r["S"], r["R"]) for r in recs])
            return None
        cnt = dr.gather(mi.UInt32, counts, parents)
        first = dr.prefix_sum(cnt)                    # exclusive: each parent's first slot
        total = int(dr.sum(cnt)[0])
        mark = dr.zeros(mi.UInt32, total)
        dr.scatter(mark, 1, first)
        rank = dr.cumsum(mark) - 1                  # inclusive
        idx = dr.gather(mi.UInt32, parents, rank)
        dr.eval(idx)
        self.stats["max_lanes"] = max(self.stats["max_lanes"], total)
        beta = dr.gather(mi.Spectrum, st["beta"] * split_weight(ns, counts), idx)
        out = dict(width=total, beta=beta,
                   eta=dr.gather(mi.Float, st["eta"], idx),
                   depth=dr.gather(mi.UInt32, st["depth"], idx),
                   sid=dr.gather(mi.UInt32, st["sid"], idx),
                   pixel=dr.gather(mi.UInt32, st["pixel"], idx),
                   classic=dr.gather(mi.Bool, st["classic"], idx),
                   hist=[dr.gather(mi.UInt32, hh, idx) for hh in st["hist"]])
        if "nee" in st:     # (the first hit: whether its copies take its light samples)
            out["nee"] = dr.gather(mi.Bool, st["nee"], idx)
        # a lane that went on alone keeps its sums; the copies of a split start from zero
        alone = dr.gather(mi.UInt32, counts, idx) == 1
        out["acc"] = [(dr.gather(mi.Float, a, idx, alone), dr.gather(mi.Float, b, idx, alone))
                      for a, b in st["acc"]]
        if "own" in st:
            out["own"] = (dr.gather(mi.Spectrum, st["own"][0], idx, alone),
                          dr.gather(mi.Float, st["own"][1], idx, alone))
        else:
            out["own"] = (dr.zeros(mi.Spectrum, total), dr.zeros(mi.Float, total))
        if self._next is not None:               # after a bounce: the ray and its hit
            ray, pi = self._next
            out["ray"] = dr.gather(mi.Ray3f, ray, idx)
            out["pi"] = dr.gather(mi.PreliminaryIntersection3f, pi, idx)
        else:                                    # the first hit (camera_hit)
            out["si"] = dr.gather(mi.SurfaceInteraction3f, st["si"], idx)
        self._next = None
        if record:
            recs.append(dict(S=dr.zeros(mi.Float, total), R=dr.zeros(mi.Float, total),
                             cell=tuple(dr.gather(mi.UInt32, c, idx) for c in cell),
                             blum=luminance(beta)))
            out["hist"].append(dr.arange(mi.UInt32, total))
            out["acc"].append((dr.zeros(mi.Float, total), dr.zeros(mi.Float, total)))
        # the gathers run inside the next bounce's kernel (nothing is evaluated here but idx)
        return out
