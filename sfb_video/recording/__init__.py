"""A rerun recording (``recording.rrd``) of a processed clip, to replay the run in the rerun viewer:
the recorder (:mod:`.recorder`), the pipe it writes through (:mod:`.pipe`) and the viewer's
layout (:mod:`.layout`).

Open it with ``rerun recording.rrd``. The file is streamed to disk while the clip is processed:
memory holds no images, only rerun's small per-chunk index (see ``WRITE_FOOTER``). It appears
under its final name only when the recorder is closed; until then it is a hidden temporary file
in the same folder (:func:`sfb_video.atomic.temporary_sibling`), removed if the run fails.

rerun encodes the file (its own file sink, footer included) but does not write it to disk: it
writes into a pipe, and a thread of ours copies the pipe into the temporary file with plain
writes
(:class:`~sfb_video.recording.pipe.Pipe`). rerun's own file writer stops at a write error (a full disk) and says so
only in its log, after which its flush times out and its disconnect waits forever; through the
pipe, which is always drained, rerun's writer never fails, and a write error is an ``OSError`` of
ours, reported as a one-line :class:`~sfb_video.errors.OutputError` at the next frame or on close.

A clip larger than 1920x1080 is recorded at 1/f of its size, f the smallest whole number that
fits it (:data:`~sfb_video.recording.recorder.MAX_VIEW`): its images, boxes, masks and the
pinhole alike, so that they line up as at full size; the 3D scene is the same.

Entity layout (what each path holds):

    world                          static ViewCoordinates RDF: world = the camera frame (OpenCV,
                                   x right, y down, z forward), so the 3D view matches the image.
    world/camera                   static Pinhole: the clip's intrinsics and resolution, camera at
                                   the world origin.
    world/camera/image             the input frame (an AV1 VideoStream, as every image below:
                                   :mod:`.video_stream`), shown in the pinhole's 2D view and on
                                   its frustum in 3D; static AnnotationContext for the mask.
    world/camera/image/detection   Boxes2D: the detected objects' boxes, labelled by track; Clear on
                                   frames without one.
    world/camera/image/mask        SegmentationImage: the detection mask (class 1 = "object",
                                   uncompressed); Clear on frames without one.
    world/camera/image/subframe_mask/track_XX  SegmentationImage, subframe timeline only: the sub-frame mask
                                   (DeFMO's; class 2 = "sub-frame mask") each fit used, in the
                                   fit's time order; only in runs with such masks.
    run/masks, run/config, run/summary, run/shapes  static TextDocuments: the masks the fits used,
                                   per track and frames ("diff", or "defmo" and whether DeFMO's
                                   order was kept or reversed); the run's resolved config; its
                                   summary.json; the shape each joint window chose and its margin.
    world/track_XX/object          Mesh3D: track XX's fitted textured mesh in object coordinates
                                   (unit scale), and Transform3D (translation + mat3x3): its pose,
                                   object -> camera coordinates.
    world/trajectory/track_XX      LineStrips3D + Points3D: track XX's 3D positions so far.
    background                     the estimated background.
    reconstruction                 I_hat, the fitted object blurred over the background.
    tsr                            the temporal super-resolution sub-frames, one per sub-frame
                                   time step; on the frame timeline a stream of its own holds
                                   each frame's middle one.
    losses/track_XX/<name>         Scalars: the final value of each loss of a frame's fit.
    fit/track_XX/<name>            Scalars, step timeline only: each loss along the optimisation
                                   of each of the track's fits, one after another.
    quality/track_XX/explained     Scalars: how much of the frame's difference the fit explains.

The layout the viewer opens on
(:func:`~sfb_video.recording.layout.layout`, sent with the recording as its blueprint): the
input frame with its detection beside the super-resolved sub-frame, the 3D view framed on the
objects' trajectories, and tabs: one per track (its losses and explained), the fits' curves on
the step timeline, the reconstruction and background, the run's text. It opens on the subframe
timeline, where every panel it shows has content.

Timelines (all sequences):

    frame      the frame index. Everything but ``fit`` and the sub-frame poses is on it (``tsr``
               by a stream of each frame's middle sub-frame); at a frame the object's
               transform is its pose at mid-exposure.
    subframe   ``frame * n + k`` for sub-frame k of the n each frame has (``subframes``): scrub it
               to play the sub-frames. ``tsr``'s every sub-frame and the pose at each sub-frame's
               mid-time live here (the poses not on ``frame``, so they cannot shadow the
               frame-level pose); everything
               else logged per frame is also stamped at ``frame * n`` so that it shows while
               scrubbing.
    step       the optimisation steps of ``fit/track_XX/<name>``, counted on across the track's
               fits (a frame's fit starts where the previous one ended), so that they read as
               one curve after another, not as a pile of curves that all start at 0.

Reading it back in Python: ``rerun.chunk.RrdReader(path).stream().to_chunks()`` gives chunks with
``entity_path`` (with a leading "/"), ``is_static``, ``timeline_names`` and ``to_record_batch()``,
whose columns are the timelines and components named "<Archetype>:<field>" (e.g.
"Transform3D:translation"); matrices are stored column-major.

Pixel convention: the project puts pixel centres at integers, rerun at half-integers (pixel (0, 0)
covers [0, 1] x [0, 1]), so the pinhole's principal point is (cx + 0.5, cy + 0.5) and a box of
pixels (x, y, w, h) spans [x, x + w] x [y, y + h].
"""

from sfb_video.recording.layout import APPLICATION_ID, layout, shape_text, track_entity
from sfb_video.recording.recorder import Recorder

__all__ = ["APPLICATION_ID", "Recorder", "layout", "shape_text", "track_entity"]
