"""Parameters of the assignment stage (stdlib only: this module must never import torch)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from dcseg.fields import option

Matcher = Literal["assignment", "matching"]
LabelMaps = Literal["gaussians", "clusters"]
Companions = Literal["any", "alone"]


@dataclass(frozen=True)
class AssignConfig:
    """How clusters get class labels from per-view class-aware 2D masks (method doc §6, B.7).

    Attributes:
        matcher: ``"assignment"`` (each class may take up to ``replicas`` clusters per view; the
            paper's best variant) or ``"matching"`` (one-to-one; the ablation).
        replicas: class replicas per view in ``"assignment"`` mode: a fixed count (paper: 3)
            or ``"components"`` = the number of connected components of the class's mask in
            that view with at least ``min_area`` pixels (1 for a class that is present only in
            smaller pieces).
        min_iou: edges with IoU below this are invalid: never matched, never voted (paper 0.05).
        min_area: smallest class-mask component (pixels) counted by ``replicas="components"``,
            at the reference's 320x240: runs scale it with their pixels
            (:func:`dcseg.sizes.min_area`).
            The same-named 2D filter of cluster masks (paper: 1000 px at 1200x680) is applied
            before this stage, when cluster maps are made.
        confusion_min_share: undo consistent class confusions (:mod:`dcseg.assign.confusion`):
            a labelled cluster's companion is the other class it is matched to in at least this
            share of its matched views (and ``confusion_min_views``), with masks that cover it
            about as well (``confusion_min_iou_ratio``); when every cluster voted a class (of
            those matched in ``confusion_min_views / confusion_min_share`` views or more) has
            a companion, that class is taken for a confusion and each of those clusters takes
            its companion. 0 = off (the vote stands). Open-vocabulary segmenters name an
            object as a look-alike in most views and right in the others: the vote, and naive
            fusion, elect the look-alike. Realistic tuning layouts 0 / 1 (24 views 320x240,
            clustering seeds 0/10, ``benchmarks/bench_segment.py``), 3D labels / maps - naive
            2D fusion, off: +3.0 / +1.4, +0.7 / +0.3; 0.1: +8.6 / +7.5, +5.3 / +4.8; 0.15:
            +8.6 / +7.5, +8.5 / +8.0; 0.2 on layout 0: +2.7 / +1.1 (too few views name the
            object right). Of the 14 clusters 0.15 relabelled, 11 became right, 2 stayed
            wrong (a ball named globe took a neighbour's teddy) and 1 right mug became teddy.
            Off by default: under per-view random class noise companions are everywhere and
            it relabels right objects (heavy held-out layout 4, 24 views, seeds 0/10: 3D
            labels / maps 76.4 / 77.9 off, 60.2 / 63.5 at 0.15; naive fusion 58.8). Opt in
            (0.15) for segmenters that confuse look-alikes consistently.
        confusion_min_views: ... the companion is matched in at least this many views.
        confusion_companion: ``"any"``, or ``"alone"``: a companion is taken only when some
            other cluster is voted it with no companion of its own
            (:func:`~dcseg.assign.confusion.named_alone`). Random per-view noise names a
            right object as its confusable class in a steady share of views, with the same
            per-cluster signature as a look-alike confusion; its companion is then a class
            no object is named alone, and ``"alone"`` leaves its vote (at 0.15, 24 views,
            seeds 0/10, 3D labels / maps: heavy held-out 4 76.4 / 77.9 = off, ``"any"`` 60.2
            / 63.5; default held-out 3 / 4 = off, ``"any"`` -1.8 / -2.2, -13.8 / -14.8).
            Realistic: held-out 7 off 36.2 / 35.2, ``"alone"`` 42.2 / 41.6, ``"any"`` 46.0 /
            46.1; tuning 0 and 1 ``"alone"`` = off (47.1 / 45.4, 41.3 / 40.8), ``"any"`` 52.7
            / 51.5, 49.1 / 48.5: their renamed objects' classes are named nowhere else
            (``results/confusion_gate.json``).
        confusion_min_iou_ratio: ... its mean matched IoU is at least this times that of the
            voted class (the whole object renamed, not a neighbour's mask bleeding in).
        min_share_ratio: after voting, a Gaussian of a labelled cluster leaves the cluster
            (becomes noise) when its own class-mask evidence — its blending weight over the
            pixels of each class, summed over views — gives the cluster's class a share below
            this fraction of the share the whole cluster gives it
            (:mod:`dcseg.assign.consistency`); 0 = off (the paper). dcseg's addition: on the
            40-view synthetic benchmark scenes, object clusters also held floor Gaussians up to
            half a metre away, labelling floor as ball, block or domino. Projection mIoU, mean
            over three reconstructions (pipeline seeds 0/1/2) x clustering seeds 0/10
            (``benchmarks/bench_robustness.py``), clean / default / heavy noise, off vs 0.5 vs
            0.6: 87.6 / 81.7 / 69.3 vs 88.0 / 86.0 / 78.1 vs 88.5 / 86.7 / 78.0. An absolute
            share floor instead (0.15; measured with the older 2D filter) erased a rare class
            that the maps miss in most views, which the relative test keeps; 0.7 started to
            erase it too, so the default stays clear of that edge.
        min_cluster_support: before the consistency step, a labelled cluster whose voted
            class gets less than this fraction of the pooled class evidence (its Gaussians'
            evidence summed) of the cluster's best-supported class takes that best class
            instead (:func:`dcseg.assign.consistency.unsupported`); 0 = every vote stands.
            The vote matches whole cluster masks by IoU: when bigger clusters take a small
            object's replicas in a view, a floor cluster beside it can win the object's class
            in a few views. Realistic masks, clustering seed 10 of layout 0: a 248-Gaussian
            floor patch 2.4 m across voted ``ball`` with ball 2.6 % of its own evidence
            (relabelling it: 42.8 -> 47.3 3D mIoU). Wrong votes had ratios 0.004-0.09,
            correct look-alike votes 0.38 and more; 0.05, 0.1 and 0.2 scored the same on
            the tuning layouts (seeds 0/10).
        support_min_extent: ... only for clusters that span at least this (metres; the
            largest side of their centres' box between the 5th and 95th percentiles,
            :func:`dcseg.assign.consistency.spread`); smaller clusters keep their vote. A rare
            small object that the class maps miss in most views has little evidence of its
            own class: on heavy layout 0 two lego clusters (21 and 28 Gaussians, ratio
            0.04-0.05) were the only lego found, and relabelling them cost 4.7 mIoU. The
            wrong votes were surface patches spanning 1-2.5 m (223-1316 Gaussians).
        support_min_iou: ... and also smaller clusters whose matched views' mean IoU (summed
            IoU votes / views matched) is below this; 0 = none. A surface fragment that
            overlaps a small object's bleeding class mask in a few views wins the object's
            class with IoU 0.06-0.18 per view (detector layout 8: tray fragments voted
            ``domino``; heavy layout 4: floor patches), where a rare object's own clusters
            matched at 0.25-0.56 (heavy 4: lego, domino). 0.15, 0.2 and 0.3 scored the same;
            0.2 against 0 (24 views, seeds 0/10, benchmarks/results/support_min_iou.json):
            heavy held-out 3, 4, 5, 9 +0.6 / +0.6 (3D / maps), F1 +0.6; detector 5, 7, 8, 9
            +0.3 / +0.7, F1 +0.8; fresh layouts (heavy 5, 9, detector 5, 9) unchanged; no
            layout x seed lower (36 pairs with clean, default, realistic and lowres).
        regroup_min_gaussians: Gaussians that the consistency step takes out of one cluster
            and that touch each other (contact radius, ``contact_factor``) form groups; a
            group of at least this many becomes a cluster of the class its pooled evidence
            supports most (:func:`dcseg.assign.consistency.rejected_groups`), so it is an
            object instance; smaller groups, and groups of a stuff class, stay noise for
            completion to fill; 0 = off. SAM-style masks merge an object with its support (a
            duck on a tray, blocks on a table): the cluster is voted for the support, the
            object's Gaussians leave it, and completion from the support around them gave
            them its class again. Off when the evidence is trusted (``trust_agreement``): a
            group pools to one class, so on clean layout 2 a group of table and domino
            Gaussians made the domino table (96 -> 79 IoU), where completion gives each
            Gaussian its own evidence's class. Sizes 20 / 50 / 100: realistic layout 1 41.1 /
            41.1 / 40.5, heavy layout 1 67.2 / 67.2 / 67.5 (instance F1 97.4 / 94.6 / 95.9 and
            96.2 / 94.9 / 94.9); 20 cost heavy layouts 0 and 2 1.0 and 0.5. Both steps, off
            -> on, 3D labels on layouts 0-2 (``benchmarks/HISTORY.md``): default +0.2 / -0.4
            / +6.4, heavy +0.4 / +6.4 / -0.6, realistic +1.8 / +4.4 / -0.6, clean unchanged.
            A group is only as right as its pooled evidence: on default layout 1 a group of
            ball Gaussians whose look-alike evidence said bowl became a bowl.
        regroup_unanimous_gaussians: ... and a smaller group of at least this many becomes
            one too when its pooled evidence is (nearly) unanimous: its top class has at least
            ``regroup_unanimous_share`` of it; 0 = off. A domino lying flat on a tray left
            the tray's cluster with all of its evidence for domino, stayed noise under 50,
            and completion from the tray round it gave it the tray's class (detector
            layout 10, one clustering seed: 7.5 mIoU; 48 Gaussians at a share of 0.945, ring
            Gaussians with the tray's evidence among them). 0 -> 20 at 0.9, 15 held-out layouts,
            24 views, seeds 0/10 (``benchmarks/results/regroup_unanimous.json``): 3D labels /
            maps / instance F1 +0.26 / +0.35 / -0.17; detector 10 +3.3 / +4.4, detector 9 +0.6 /
            +0.8 / F1 -2.5 (a block's group is an instance more), the rest within 0.05.
        regroup_unanimous_share: the share of a small group's pooled evidence its top class
            needs (``regroup_unanimous_gaussians``); in [0, 1]. 0.95 missed the domino.
        ring_plane_tol: give the support rings of objects back to their support
            (:mod:`dcseg.assign.rings`): a Gaussian of an object's cluster (a labelled
            cluster, not of a stuff class) within this distance (metres) of the local plane
            of a bigger neighbouring labelled cluster (the table or floor it stands on, within
            ``ring_radius``), with its disc facing that plane's normal (``ring_min_cosine``),
            joins that cluster; ``ring_rounds`` rounds grow the support over the ring; 0 =
            off. Box-prompted masks (Grounded-SAM style) take the table top round an object's
            base in every view, so votes and evidence both name the ring the object. 24 views
            320x240, seeds 0/10 (``benchmarks/results/support_rings.json``), 3D labels / maps /
            instance F1, off -> 1.5 cm, held-out layouts: detector 5, 7, 9, 10 +1.6 / +1.6 /
            +7.4 on average (-0.3 to +2.4 on 3D labels); realistic 7, lowres 7, heavy 9, 10,
            default 3, 5, clean 3 -0.3 / -0.2 / -0.3 (worst -0.8). Chosen on detector 8 (1.0
            and 2.0 cm, 5 cm radius scored lower); the enclosure, rise and flat-cluster checks
            of :mod:`dcseg.assign.rings` after heavy 4, 5 and lowres 8 lost objects' parts.
            Since 2026-12-07 only bodies of the moved cluster's own class enclose beyond
            ``ring_radius`` (other objects 10-40 cm round a ring kept it): detector 5, 7, 8, 9,
            10 +0.8 / +0.7 / F1 +1.6; the other 10 layouts -0.1 / -0.1 / -0.3 (benchmarks README).
        ring_radius: ... the support's local plane is fitted to its Gaussians within this
            distance (metres) of the candidate.
        ring_min_cosine: ... smallest |cosine| between the candidate's disc normal and the
            support's local plane normal.
        ring_max_share: ... an object cluster that would lose more than this share of its
            Gaussians keeps them all (it lies flat on its support: a poster on a wall, a
            rug, a domino lying flat), unless Gaussians of its class that rise from the
            support lie within ``ring_radius`` of them (then it is a piece of the support
            that this object's masks took).
        ring_rounds: ... rounds of growing the supports.
        objects: turn clusters into object instances (:mod:`dcseg.assign.instances`); False =
            one instance per cluster (the paper). Clusters stay available as the cluster level.
        contact_factor: two Gaussians touch when their centres are closer than this many times
            the median nearest-neighbour spacing of the scene's Gaussians; used for cluster
            adjacency and label completion. The median comes from the dense objects; walls are
            sparser: on the 40-view synthetic scenes each wall's Gaussians fall apart into
            thousands of pieces at 3x and are connected at 6x.
        neighbours: nearest neighbours looked at per Gaussian (adjacency and completion).
        min_contacts: clusters are adjacent when at least this many of their Gaussians touch.
        merge_min_cosine: adjacent clusters of one (non-stuff) class merge into one object when
            the cosine of their unit feature centres is at least this.
        merge_min_vote_cosine: ... and when their class-vote vectors over views (the
            assignment's ``votes`` rows) have at least this cosine (they agree across views).
        merge_near: merge objects of one class whose nearest Gaussians are within the contact
            radius and whose mean features agree
            (:func:`dcseg.assign.instances.merge_near_objects`): an object cut into clusters
            of 10-30 Gaussians (a ball, a mug) has pieces that touch along a seam of 2-4
            contacts or not at all, which ``min_contacts`` never accepts.
            Tuned on layouts 0-2 (clustering seeds 0/10, ``benchmarks/bench_segment.py``):
            instance F1 on clean masks off / on 97.3-87.8 / 97.4-97.4, 97.3-97.3 / 100-100,
            70.0-84.2 / 97.3-97.3 (28-25 -> 21 instances for 18 objects); default noise
            unchanged (100, 97.4, 94.4 on all three layouts).
        near_min_cosine: ... the smallest cosine of the two objects' mean features. On the
            tuning layouts the pieces of one object had 0.41-0.72 (one split block -0.10) and
            the only distinct same-class objects that close, two tables, -0.38; 0.5 instead of
            0.3 left clean layout 0 at 100 / 97.4 with 24-25 instances.
        stuff_classes: class names that are surfaces, not objects: each connected surface of
            such a class is one region, whatever its clusters (names absent from the
            vocabulary are ignored; empty = every class is an object class).
        unlabelled_id: a class-map value that means "no class" (its pixels are unlabelled, not
            votes for the vocabulary's class of that index), in addition to each format's own
            unlabelled values (:mod:`dcseg.io.semantic`); None = only those. ScanNet's
            ``label-filt`` PNGs use 0 for unannotated pixels.
        surface_min_normal_cosine: two touching clusters of a stuff class are one surface when
            the |cosine| of their plane normals (least-variance direction of each cluster's
            Gaussian centres) is at least this (0.8 = 37 degrees) ...
        surface_max_tilt: ... and the step between their centroids lies in both planes: its
            |cosine| with either normal is at most this (0.3 = 17 degrees). Walls meeting at a
            corner fail both tests and stay two regions, as do a floor and a raised platform.
        split_stuff_planes: split every stuff region into planes after merging: its
            Gaussians' local normals are grouped by direction (``surface_min_normal_cosine``)
            and each direction into connected pieces, so one cluster that wraps round a
            corner gives two walls (:func:`dcseg.assign.planes.split_stuff_planes`).
        plane_min_share: a normal direction must hold at least this share of its region's
            Gaussians to become a plane of its own (smaller groups of normals, e.g. a
            skirting board's edge, join their neighbours' plane).
        min_instance_gaussians: objects and stuff regions with fewer Gaussians are left out of
            the instance list (their Gaussians keep their class, instance -1).
        min_fragment_share: an object with fewer Gaussians than this share of the largest
            object of its class (stuff excluded) is a fragment of one of them: it
            dissolves, and its Gaussians join a near object of their class or stay out of the
            instance list (keeping their class). A class with one object keeps it, however
            small; 0 = off. Tuned on layouts 0-2 (clean and default noise, clustering seeds
            0/1, ``benchmarks/bench_segment.py``): 0 / 0.1 / 0.15 / 0.2 / 0.3 gave clean
            layout 0 instance F1 83-85 / 85 / 94 / 94 / 91-94 with 34-36 / 28 / 22-24 / 21-22 /
            18-19 instances for 19 objects; default layout 0 92-97 / 95-100 / 97-100 / 97-100 /
            91-97 (recall falls: real objects dissolve), so the default sits at the low end
            of the 0.15-0.2 plateau.
        complete: label completion (:mod:`dcseg.assign.completion`): unlabelled Gaussians next
            to labelled ones take a class from their neighbours and their own class evidence.
        completion_rounds: passes of completion; each reaches one neighbourhood further.
        evidence_weight: weight of a Gaussian's own class-evidence share against its
            neighbours' class share in completion.
        background_share: a Gaussian that puts more than this share of its blending weight
            (over the views with class maps) on pixels the class maps leave unlabelled is
            background: it has no class in the end, completion gives it none, and an
            unlabelled cluster made mostly of such Gaussians adopts none
            (:mod:`dcseg.assign.adoption`); 1 = off. Masks that label only some things leave
            the rest unlabelled on purpose (ground truth with 0 = background, a detector
            prompted for a few classes); before 2026-12-07 adoption spread the objects'
            classes over it chain by chain and the objects' clusters kept what they took of
            it: on a real RealSense shelf capture run with its ground-truth masks (4 objects,
            benchmarks README "Masks that label only the objects"), the label maps' mean
            object IoU against those masks was 24.2 and 85 % of the background was labelled an
            object; 78.7 and 4.5 % now (0.5: 81.5 and 1.3 %, but on detector layout 5 a ball
            that the detector misses in most of the views of its far side lost 7 % of its
            points). 15 synthetic layouts (clean, default, heavy, detector, lowres, realistic)
            move by 0.03 at most: their masks leave a Gaussian unlabelled in holes and misses.
        trust_agreement: when the class-aware masks agree with the labelled clusters at
            least this much (:func:`dcseg.assign.consistency.mask_agreement`, over the
            Gaussians of labelled clusters before the consistency step), each Gaussian's own
            evidence is trusted: the consistency step and completion use
            ``trusted_share_ratio`` and ``trusted_evidence_weight`` instead of
            ``min_share_ratio`` and ``evidence_weight``, so boundary Gaussians follow their own
            evidence rather than their cluster. None = never. The agreement is recorded in
            ``run.json`` (``segmentation.mask_agreement``). Tuned on layouts 0-2
            (``benchmarks/bench_segment.py`` runs, clustering seeds 0/10): the agreement was
            0.991-0.992 on clean masks, 0.971-0.972 at default noise, 0.938-0.948 heavy and
            0.921-0.959 realistic. Trusted evidence on clean layouts 0 / 1 / 2, 3D labels
            92.3 / 90.6 / 92.5 -> 93.4 / 90.3 / 92.7, maps 89.5 / 87.4 / 89.4 -> 90.2 / 87.2 /
            89.7 (the 3D vote: 93.5 / 90.7 / 92.6); forced on noisy masks (seed 0) it cost
            default layout 0 2.7 and heavy layout 0 7 mIoU, gained 0.3 on default layout 2 and
            2.6 on realistic layout 0, whose coarse class maps put floor in object clusters:
            per-Gaussian evidence is only as good as the masks, and the agreement does not
            tell realistic masks from heavy ones, so only near-perfect masks are trusted.
            Shares 0.7 / 0.8 / 0.9 with weights 3 / 10 were tried on clean; 0.9 and 10 were
            best on average.
        trusted_share_ratio: ``min_share_ratio`` when the evidence is trusted.
        trusted_evidence_weight: ``evidence_weight`` when the evidence is trusted.
        trusted_follow_ratio: ``follow_evidence_ratio`` when the evidence is trusted.
        follow_evidence_ratio: after adoption and completion, every Gaussian whose own
            evidence gives its class a share below this ratio of its best class's share takes
            that class (:func:`dcseg.assign.consistency.follow_evidence`); 0 = off. Trusted
            evidence sets it to ``trusted_follow_ratio``: the consistency step only reaches
            the members of labelled clusters, and the Gaussians of adopted clusters, of
            merged fragments and of completion kept classes that near-perfect masks
            contradict. Clean tuning layouts 0 / 1 / 2 (clustering seeds 0/10,
            ``benchmarks/bench_segment.py``), off / 0.9 / 0.95: 3D labels 91.4 / 91.6 / 90.5,
            90.3 / 91.0 / 91.0, 93.0 / 93.3 / 93.4; maps 89.7 / 89.8 / 90.2, 87.6 / 87.7 /
            87.8, 89.7 / 90.1 / 90.1 (the 3D vote: 90.1 / 91.0 / 93.4 and 90.2 / 87.8 /
            90.1). 0.95 is the value at which no tuning layout falls below the vote in either
            protocol (0.9: -0.37 on layout 0's maps). Cost: instance F1 100 / 97.4 / 97.3 ->
            97.3 / 97.4 / 97.3 at both (layout 0's 22-point domino loses Gaussians to the
            floor and its instance falls below IoU 0.5). 1.0 is the 3D vote wherever there
            is evidence (layout 0 3D 90.1); moving only Gaussians outside objects (and in
            stuff) kept the instance and lost the gains (91.4 / 90.3 / 93.2 at 0.9).
        label_maps: what the rendered label maps (``labels/``) show: ``"gaussians"`` = per pixel
            the class with the largest blending weight summed over the Gaussians of that class,
            each Gaussian with its final class (after the consistency step, adoption of
            unlabelled clusters and label completion: the classes the PLY carries), so maps
            and 3D labels agree; ``"clusters"`` = the cluster maps through each cluster's
            class (the paper), which the per-Gaussian steps never reach. Cluster maps always
            pass the 2D component filter (``MaskConfig``); label maps from the Gaussians only
            with ``filter_label_maps``.
        filter_label_maps: apply the cluster maps' 2D component filter to label maps rendered
            from the Gaussians too. Off: the filter exists so that specks do not vote in the
            assignment; in the output it erased small objects (a 20-point lego, a domino) from
            the maps while the 3D labels kept them. Layouts 0-2, clustering seeds 0/10,
            rendered-map mIoU off / on: clean 90.16 / 90.16, 88.69 / 87.21, 89.69 / 89.69;
            heavy 82.10 / 82.14, 61.11 / 61.08, 80.46 / 80.49; realistic 43.09 / 43.11,
            36.58 / 36.58.
    """

    matcher: Matcher = option(
        "assignment",
        choices=("assignment", "matching"),
        help="class replication (assignment) or one-to-one",
        flag="--matcher",
        group="segment",
    )
    replicas: int | Literal["components"] = 3
    min_iou: float = 0.05
    min_area: int = 1000
    confusion_min_share: float = option(
        0.0,
        bounds=(0.0, 1.0),
        help="undo consistent look-alike confusions: a class whose every cluster is also named "
        "one other class in at least this share of its views gives way to it (0 = off; 0.15 "
        "for segmenters that confuse look-alikes in most views; hurts random per-view noise)",
        flag="--confusion-min-share",
        group="segment",
    )
    confusion_min_views: int = 2
    confusion_min_iou_ratio: float = 0.5
    confusion_companion: Companions = option(
        "any",
        choices=("any", "alone"),
        help="which companions the confusion step takes: any, or alone = only a class the "
        "scene also names alone for another object (safe under random per-view noise; loses "
        "the relabels of objects whose true class no other object shows)",
        flag="--confusion-companion",
        group="segment",
    )
    min_share_ratio: float = 0.5
    min_cluster_support: float = 0.1
    support_min_extent: float = 0.5
    support_min_iou: float = 0.2
    regroup_min_gaussians: int = 50
    regroup_unanimous_gaussians: int = 20
    regroup_unanimous_share: float = 0.9
    ring_plane_tol: float = 0.015
    ring_radius: float = 0.1
    ring_min_cosine: float = 0.8
    ring_max_share: float = 0.5
    ring_rounds: int = 4
    objects: bool = True
    contact_factor: float = 6.0
    neighbours: int = 8
    min_contacts: int = 5
    merge_min_cosine: float = 0.5
    merge_min_vote_cosine: float = 0.5
    merge_near: bool = True
    near_min_cosine: float = 0.3
    stuff_classes: tuple[str, ...] = option(
        ("wall", "floor", "ceiling"),
        help="class names that are surfaces, not objects: each connected surface of one is a "
        "region, not object instances (comma-separated on the command line; empty = none)",
        flag="--stuff-classes",
        group="segment",
    )
    unlabelled_id: int | None = option(
        None,
        bounds=(0, 65535),
        help="the value that marks unlabelled pixels in the class maps, besides each format's "
        "own (255 / 65535 in PNGs, negative in .npy), e.g. 0 for ScanNet's unannotated",
        flag="--unlabelled-id",
        group="segment",
    )
    surface_min_normal_cosine: float = 0.8
    surface_max_tilt: float = 0.3
    split_stuff_planes: bool = True
    plane_min_share: float = 0.1
    min_instance_gaussians: int = 20
    min_fragment_share: float = 0.15
    trust_agreement: float | None = 0.985
    trusted_share_ratio: float = 0.9
    trusted_evidence_weight: float = 10.0
    follow_evidence_ratio: float = 0.0
    trusted_follow_ratio: float = 0.95
    complete: bool = True
    completion_rounds: int = 3
    evidence_weight: float = 1.0
    background_share: float = option(
        0.8,
        bounds=(0.0, 1.0),
        help="a Gaussian with more than this share of its weight on pixels the class maps "
        "leave unlabelled is background and gets no class (masks that label only some "
        "things); 1 = off, for masks that abstain where unsure",
        flag="--background-share",
        group="segment",
    )
    label_maps: LabelMaps = option(
        "gaussians",
        choices=("gaussians", "clusters"),
        help="rendered label maps from the Gaussians' final classes (gaussians, as in the "
        "labelled PLY) or from the cluster maps through each cluster's class (clusters)",
        flag="--label-maps",
        group="segment",
    )
    filter_label_maps: bool = False

    def __post_init__(self) -> None:
        if self.matcher not in ("assignment", "matching"):
            raise ValueError(f"matcher must be 'assignment' or 'matching', got {self.matcher!r}")
        if self.replicas != "components" and not (
            isinstance(self.replicas, int) and self.replicas >= 1
        ):
            raise ValueError(f"replicas must be an int >= 1 or 'components', got {self.replicas!r}")
        if not 0.0 < self.min_iou <= 1.0:
            raise ValueError(f"min_iou must be in (0, 1], got {self.min_iou}")
        if not 0.0 <= self.confusion_min_share <= 1.0:
            raise ValueError(
                f"confusion_min_share must be in [0, 1], got {self.confusion_min_share}"
            )
        if self.confusion_companion not in ("any", "alone"):
            raise ValueError(
                f"confusion_companion must be 'any' or 'alone', got {self.confusion_companion!r}"
            )
        if self.confusion_min_views < 1:
            raise ValueError(f"confusion_min_views must be >= 1, got {self.confusion_min_views}")
        if not self.confusion_min_iou_ratio >= 0.0:
            raise ValueError(
                f"confusion_min_iou_ratio must be >= 0, got {self.confusion_min_iou_ratio}"
            )
        if not 0.0 <= self.min_share_ratio <= 1.0:
            raise ValueError(f"min_share_ratio must be in [0, 1], got {self.min_share_ratio}")
        if not self.support_min_extent >= 0.0:
            raise ValueError(f"support_min_extent must be >= 0, got {self.support_min_extent}")
        if not 0.0 <= self.support_min_iou <= 1.0:
            raise ValueError(f"support_min_iou must be in [0, 1], got {self.support_min_iou}")
        if not 0.0 <= self.min_cluster_support <= 1.0:
            raise ValueError(
                f"min_cluster_support must be in [0, 1], got {self.min_cluster_support}"
            )
        self._check_rings()
        if self.min_area < 0:
            raise ValueError(f"min_area must be >= 0, got {self.min_area}")
        if self.label_maps not in ("gaussians", "clusters"):
            raise ValueError(
                f"label_maps must be 'gaussians' or 'clusters', got {self.label_maps!r}"
            )
        self._check_objects()
        self._check_classes()

    def _check_classes(self) -> None:
        names = self.stuff_classes
        if not isinstance(names, tuple) or not all(isinstance(n, str) and n.strip() for n in names):
            raise ValueError(
                f"stuff_classes must be a tuple of non-blank class names, got {names!r}"
            )
        unlabelled = self.unlabelled_id
        if unlabelled is not None and (
            isinstance(unlabelled, bool)
            or not isinstance(unlabelled, int)
            or not 0 <= unlabelled <= 65535
        ):
            raise ValueError(
                f"unlabelled_id must be an int in [0, 65535] or None, got {unlabelled!r}"
            )

    def _check_rings(self) -> None:
        for name, length in (("ring_plane_tol", self.ring_plane_tol),
                             ("ring_radius", self.ring_radius)):  # fmt: skip
            if not length >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {length}")
        if self.ring_plane_tol > 0 and not self.ring_radius > 0:
            raise ValueError(
                f"ring_radius must be > 0 with ring_plane_tol on, got {self.ring_radius}"
            )
        for name, share in (("ring_min_cosine", self.ring_min_cosine),
                            ("ring_max_share", self.ring_max_share),
                            ("regroup_unanimous_share", self.regroup_unanimous_share),
                            ("background_share", self.background_share)):  # fmt: skip
            if not 0.0 <= share <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {share}")
        if self.ring_rounds < 1:
            raise ValueError(f"ring_rounds must be >= 1, got {self.ring_rounds}")

    def _check_objects(self) -> None:
        positive = {"contact_factor": self.contact_factor, "neighbours": self.neighbours}
        for name, value in positive.items():
            if value <= 0:
                raise ValueError(f"{name} must be > 0, got {value}")
        counts = {
            "min_contacts": self.min_contacts,
            "min_instance_gaussians": self.min_instance_gaussians,
            "completion_rounds": self.completion_rounds,
            "regroup_min_gaussians": self.regroup_min_gaussians,
            "regroup_unanimous_gaussians": self.regroup_unanimous_gaussians,
        }
        for name, count in counts.items():
            if count < 0:
                raise ValueError(f"{name} must be >= 0, got {count}")
        for name, cos in (
            ("merge_min_cosine", self.merge_min_cosine),
            ("merge_min_vote_cosine", self.merge_min_vote_cosine),
            ("near_min_cosine", self.near_min_cosine),
            ("surface_min_normal_cosine", self.surface_min_normal_cosine),
            ("surface_max_tilt", self.surface_max_tilt),
        ):
            if not -1.0 <= cos <= 1.0:
                raise ValueError(f"{name} must be in [-1, 1], got {cos}")
        if not 0.0 < self.plane_min_share <= 1.0:
            raise ValueError(f"plane_min_share must be in (0, 1], got {self.plane_min_share}")
        if not 0.0 <= self.min_fragment_share <= 1.0:
            raise ValueError(f"min_fragment_share must be in [0, 1], got {self.min_fragment_share}")
        if self.trust_agreement is not None and not 0.0 <= self.trust_agreement <= 1.0:
            raise ValueError(
                f"trust_agreement must be in [0, 1] or None, got {self.trust_agreement}"
            )
        if not 0.0 <= self.trusted_share_ratio <= 1.0:
            raise ValueError(
                f"trusted_share_ratio must be in [0, 1], got {self.trusted_share_ratio}"
            )
        for name, ratio in (
            ("follow_evidence_ratio", self.follow_evidence_ratio),
            ("trusted_follow_ratio", self.trusted_follow_ratio),
        ):
            if not 0.0 <= ratio <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {ratio}")
        if self.trusted_evidence_weight < 0:
            raise ValueError(
                f"trusted_evidence_weight must be >= 0, got {self.trusted_evidence_weight}"
            )
        if self.evidence_weight < 0:
            raise ValueError(f"evidence_weight must be >= 0, got {self.evidence_weight}")
