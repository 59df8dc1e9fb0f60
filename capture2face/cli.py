"""The ``capture2face`` command line: a thin shell over the Python API.

Every command maps its arguments onto one API call. Errors a user can fix
(:class:`capture2face.errors.CaptureError`) print one line on stderr and exit with
code 2; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from capture2face import batch, bench, pipeline
from capture2face.calibration import ActorCalibration
from capture2face.calibration.attach import attach
from capture2face.character.load import load_character
from capture2face.errors import CaptureError, exit_interrupted, install_process_defaults
from capture2face.eval import characters, shading
from capture2face.eval.fidelity import evaluate_fidelity, table
from capture2face.eval.synthetic import evaluate_synthetic, summary_line
from capture2face.eval.synthetic_actor import actor_summary_line, evaluate_actor_synthetic
from capture2face.gltf import export_glb
from capture2face.gltf.arkit_export import export_arkit_character
from capture2face.io.atomic import write_text_atomic
from capture2face.io.paths import readable_streams
from capture2face.io.staging import check_output_file
from capture2face.io.video_input import open_video
from capture2face.models.face_model import find_face_model
from capture2face.pipeline import RunOptions
from capture2face.pipeline.calibration import (
    calibration_summary,
    check_calibration,
    learn_calibration,
    resolve_calibration,
)
from capture2face.pipeline.options import MAX_SIZE, MIN_SIZE, MOVED_TO_STAGES
from capture2face.pipeline.preflight import check_neutral_frame
from capture2face.render.renderer import WRINKLE_DRIVERS
from capture2face.rig.avatar import default_avatar
from capture2face.rig.maps import write_maps
from capture2face.runtime.log import warnings_to_stderr
from capture2face.runtime.moved_options import set_path
from capture2face.synth import SynthOptions, synthesize
from capture2face.synth.trajectories import STARTS
from capture2face.tracking import TrackOptions, track_clip
from capture2face.tracking.landmarker import defer_pyplot
from capture2face.tracking.overlay import write_overlay


def _check_avatar_args(args: argparse.Namespace) -> None:
    """``avatar``'s flags, before the avatar is built: the --export-arkit options without
    it, and files that could not be written (a folder, a .gltf name for binary glTF)."""
    if not args.export_arkit:
        given = [f for f, v in (("--quantize", args.quantize), ("--skeleton", args.skeleton),
                                ("--body", args.body), ("--naming", args.naming)) if v]
        if given:
            raise CaptureError(f"{', '.join(given)} only appl{'ies' if len(given) == 1 else 'y'} to "
                               "--export-arkit GLB; add it or leave them out")
    for flag, path in (("--export", args.export), ("--export-arkit", args.export_arkit)):
        if path and Path(path).suffix.lower() == ".gltf":
            raise CaptureError(f"{flag} {path}: writes binary glTF; name the file "
                               f"{Path(path).with_suffix('.glb')}")
        if path:
            check_output_file(path, flag, (".glb",))
    if args.save:
        check_output_file(args.save, "--save", (".npz",))


def _cmd_avatar(args: argparse.Namespace) -> int:
    _check_avatar_args(args)
    rig = default_avatar(variant=args.variant)
    if args.maps:
        write_maps(rig, args.maps)
        print(f"wrote the textures and masks of '{rig.name}' to {args.maps}")
    if args.export:
        export_glb(rig, args.export)
        print(f"wrote {args.export}")
    if args.export_arkit:
        export_arkit_character(rig, args.export_arkit, naming=args.naming or "_L", quantize=args.quantize,
                               skeleton=args.skeleton, body=args.body)
        print(f"wrote {args.export_arkit}")
    if args.save:
        rig.save(args.save)
        print(f"wrote {args.save}")
    if not (args.maps or args.export or args.save or args.export_arkit):
        print(
            f"{rig.name}: {rig.n_vertices} vertices, {len(rig.triangles)} triangles, "
            f"{rig.n_bones} bones, {rig.n_morphs} morph targets, poses {', '.join(rig.pose_names)}"
        )
    return 0


def _cmd_synth(args: argparse.Namespace) -> int:
    opts = SynthOptions(
        frames=args.frames, seed=args.seed, size=args.size, fps=args.fps,
        head_motion=not args.no_head_motion, expression=not args.no_expression,
        face_exit=args.face_exit, variant=args.variant, start=args.start, rom=args.rom,
    )
    actor = None if args.actor in (None, "default") else load_character(args.actor)
    synthesize(args.output, opts, progress=not args.quiet, actor=actor)
    print(f"wrote {args.output} and {Path(args.output).with_suffix('.truth.npz')}")
    return 0


#: Each option flag's place in RunOptions (``--no-audio`` apart: ``audio`` is its negation): the
#: flags named as RunOptions' flat keywords of before, each where it moved.
FLAG_OPTIONS = {"character": ("character",), **MOVED_TO_STAGES, "calibration": ("track", "calibration"),
                "allow_truncated": ("allow_truncated",)}


def options_from_args(args: argparse.Namespace) -> RunOptions:
    """The RunOptions a command's flags ask for: the one place flags become options (``run``,
    ``batch``, and ``track`` through its ``track``); a flag the command lacks keeps the default."""
    options = RunOptions()
    for flag, path in FLAG_OPTIONS.items():
        if hasattr(args, flag):
            set_path(options, path, getattr(args, flag))
    if hasattr(args, "no_audio"):
        options.audio = not args.no_audio
    return options


def _track_options(args: argparse.Namespace) -> TrackOptions:
    """The ``track`` command's TrackOptions, checked (TrackOptions.validate's bounds)."""
    options = options_from_args(args).track
    options.validate()
    return options


def _cmd_track(args: argparse.Namespace) -> int:
    # Before tracking: the options, the clip decodes, the neutral frame lies inside it,
    # the model exists.
    options = _track_options(args)
    check_neutral_frame(args.neutral_frame, open_video(args.clip))
    check_calibration(options)
    check_output_file(args.output, "-o", protect=[args.clip])
    if args.overlay:
        check_output_file(args.overlay, "--overlay", (".mp4",), protect=[args.clip, args.output])
    find_face_model(args.face_model)
    calibration = resolve_calibration(options, progress=not args.quiet)
    track = track_clip(args.clip, options, progress=not args.quiet)
    if calibration is not None:  # the track carries it (track.npz keeps it)
        track = attach(track, calibration)
    track.save(args.output)
    if args.overlay:
        write_overlay(args.clip, track, args.overlay, progress=not args.quiet)
    print(
        f"{args.output}: {track.n_frames} frames, {track.tracked_frames} with a face, "
        f"neutral frame {track.neutral_frame}, rest: {track.rest_source}"
    )
    return 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    # Before tracking: the options, the takes decode, the output can be written, the model exists.
    options = _track_options(args)
    for take in args.takes:
        open_video(take)
    check_output_file(args.output, "-o", (".json",), protect=args.takes)
    find_face_model(args.face_model)
    learned = [learn_calibration(take, options, progress=not args.quiet) for take in args.takes]
    calibration = ActorCalibration.together(learned)
    calibration.save(args.output)
    for take, one in zip(args.takes, learned, strict=True):
        for warning in one.warnings:
            print(f"capture2face: warning: {take + ': ' if len(learned) > 1 else ''}{warning}", file=sys.stderr)
    print(f"wrote {args.output}: {calibration_summary(calibration)}")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    opts = options_from_args(args)
    report = pipeline.run(args.clip, args.output, opts, progress=not args.quiet, name=args.name)
    for warning in report["warnings"]:  # also in report.json
        print(f"capture2face: warning: {warning}", file=sys.stderr)
    print(f"wrote {report['output_dir']} ({report['frames']} frames, {report['fps_processing']:.1f} fps)")
    return 0


def _print_json(result: dict, path: str | None) -> None:
    """``result`` as JSON on stdout and, with ``path``, written there (atomically)."""
    text = json.dumps(result, indent=2)
    if path:
        write_text_atomic(path, text + "\n")
    print(text)


def _cmd_eval(args: argparse.Namespace) -> int:
    if args.actor is not None or args.target is not None:
        return _cmd_eval_actor(args)
    if args.calibration:
        raise CaptureError("--calibration needs an ARKit character as the --actor (it performs the ROM take)")
    result = evaluate_synthetic(
        frames=args.frames, seed=args.seed, target_variant=args.target_variant,
        size=args.size, progress=not args.quiet, start=args.start,
    )
    _print_json(result, args.json)
    if not args.quiet:  # the ratios and goals at a glance; stdout stays plain JSON
        print(summary_line(result, "truth's neutral"), file=sys.stderr)
        if "auto_neutral" in result:
            print(summary_line(result["auto_neutral"], "tracker's neutral"), file=sys.stderr)
    return 0


def _cmd_eval_actor(args: argparse.Namespace) -> int:
    """``eval synthetic --actor / --target``: any characters (eval.synthetic_actor)."""
    if args.target_variant is not None or args.start != "rest":
        raise CaptureError("--target-variant and --start go with the default avatar's loop; "
                           "leave them out with --actor / --target")
    result = evaluate_actor_synthetic(args.actor, args.target, frames=args.frames, seed=args.seed,
                                      size=args.size, progress=not args.quiet, calibration=args.calibration)
    _print_json(result, args.json)
    if not args.quiet:
        print(actor_summary_line(result, "truth's neutral"), file=sys.stderr)
    return 0


def _cmd_eval_fidelity(args: argparse.Namespace) -> int:
    result = evaluate_fidelity(args.paths, character=args.character, plot_dir=args.plots,
                               progress=not args.quiet)
    if args.json:
        write_text_atomic(args.json, json.dumps(result, indent=2) + "\n")
    print(table(result["clips"]))
    print(result["summary"])
    return 0


def _cmd_eval_shading(args: argparse.Namespace) -> int:
    results = [shading.shading_of(path, progress=not args.quiet) for path in args.runs]
    summary = shading.summary_line(results)
    if args.json:
        write_text_atomic(args.json, json.dumps({"runs": results, "summary": summary}, indent=2) + "\n")
    for r in results:
        print(f"{r['run']}: skin darkening p95 " + ", ".join(f"{k} {v:.1%}" for k, v in r["darkening_p95"].items())
              + f"; mouth opening r {r['mouth_open_r']:.2f} gain {r['mouth_open_gain']:.2f}, brows r "
              f"{r['brows_r']:.2f} gain {r['brows_gain']:.2f}, eyes r {r['eyes_r']:.2f} gain {r['eyes_gain']:.2f}")
    print(summary)
    return 0


def _cmd_eval_characters(args: argparse.Namespace) -> int:
    result = characters.evaluate_characters(args.characters, clip=args.clip, out_dir=args.output, size=args.size,
                                            cell=args.cell, track_file=args.track, progress=not args.quiet)
    if args.json:
        write_text_atomic(args.json, json.dumps(result, indent=2) + "\n")
    print(characters.table(result["characters"]))
    print(result["summary"])
    return 0


def _cmd_batch(args: argparse.Namespace) -> int:
    opts = options_from_args(args)
    report = batch.run_batch(args.inputs, args.output, opts, jobs=args.jobs, resume=args.resume,
                       ray_address=args.ray, progress=not args.quiet)
    failed = report["summary"]["failed"]  # this batch's (the report also keeps earlier entries)
    print(f"{sum(report['summary'][s] for s in ('ok', 'failed', 'skipped', 'pending'))} clips, {failed} failed; "
          f"see {Path(args.output) / 'batch_report.json'}")
    return 1 if failed else 0


def _cmd_bench(args: argparse.Namespace) -> int:
    if args.calibration:
        result = bench.calibration_bench(size=args.size, progress=not args.quiet)
    elif args.memory_seconds:
        result = bench.memory_check(long_seconds=args.memory_seconds, size=args.size, progress=not args.quiet)
    else:
        result = bench.run_bench(size=args.size, frames=args.frames, progress=not args.quiet)
    _print_json(result, args.json)
    if not args.quiet:  # the main figures and goals at a glance; stdout stays plain JSON
        print(bench.summary_line(result), file=sys.stderr)
    return 0


NEUTRAL_HELP = ("index of a frame with the actor's face at rest (default: each region's rest, brows, eyes "
                "and mouth, found in the clip); must lie inside the clip")


def _add_neutral_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--neutral-frame", type=int, default=None, metavar="N", help=NEUTRAL_HELP)
    p.add_argument("--neutral-image", metavar="IMAGE", default=None,
                   help="a photo or still of the same actor at rest, instead (as Live Link Face's calibration)")
    p.add_argument("--neutral-clip", metavar="VIDEO", default=None,
                   help="a short take of the same actor at rest, instead")
    _add_calibration_option(p)


def _add_calibration_option(p: argparse.ArgumentParser, batch: bool = False) -> None:
    p.add_argument("--calibration", metavar="ROM_OR_JSON", default=None,
                   help=("the actor's calibration" + (" for every clip (else CLIP.rom.mp4 or CLIP.rom.json beside "
                                                      "a clip, for that clip)" if batch else "") +
                         ": a range-of-motion take (docs/calibration.md), learned first, or the actor.json "
                         "`capture2face calibrate` wrote"))


def _common_options() -> argparse.ArgumentParser:
    """The global flags as a parent parser for every subparser."""
    # The global flags work before and after the subcommand (`capture2face -q run ...` and
    # `capture2face run ... -q`): every subparser has them too, defaulting to SUPPRESS so
    # that a subparser never overwrites what the main parser saw.
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show tracebacks on errors")
    common.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                        help="no progress bars")
    return common


def _add_face_model_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--face-model", metavar="PATH", default=None,
                   help="MediaPipe face_landmarker.task (default: $CAPTURE2FACE_FACE_MODEL, "
                        "else the one bundled in capture2face/models)")


def _add_face_choice_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--faces", choices=("largest", "center"), default="largest",
                   help="several faces in view: track the largest (default) or the one nearest "
                        "the centre, then the one continuing it; report.json warns how many were seen")
    p.add_argument("--face", type=int, default=None, metavar="N",
                   help="instead, track face N (0-based, left to right) of the first frame with "
                        "more than N faces, then the one continuing it")
    p.add_argument("--track-workers", type=int, default=None, metavar="N",
                   help="MediaPipe landmarkers tracking segments of a clip at once, one process "
                        "each (default: one per free core; batch: one per clip when clips run in parallel)")


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """The options `run` and `batch` share (RunOptions)."""
    p.add_argument("--character", metavar="FILE", default=None,
                   help="a FaceRig .npz, a .glb or a .vrm: ARKit-named morphs, visemes, VRM presets and Rocketbox "
                        "expressions need nothing else; a mapping .json beside it for face bones or other "
                        "morph names")
    p.add_argument("--wrinkles", choices=WRINKLE_DRIVERS, default="auto",
                   help="wrinkle driver: auto (each bone's progress to the reference poses, "
                        "default), zones (masked face zones), dynamic (the mesh's area change "
                        "each frame), off")
    p.add_argument("--size", type=int, default=512,
                   help=f"render size in pixels, square, even, {MIN_SIZE}..{MAX_SIZE} (default: 512)")
    p.add_argument("--allow-truncated", action="store_true",
                   help="process the frames before the damage of a truncated or corrupt clip "
                        "(with a warning) instead of failing")
    p.add_argument("--no-audio", action="store_true",
                   help="leave the clip's audio out of avatar.mp4 and compare.mp4")
    _add_face_model_option(p)
    _add_face_choice_options(p)


def _add_avatar_parser(sub, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("avatar", parents=[common], help="build the default avatar; write its maps or a .glb")
    p.add_argument("--maps", metavar="DIR", help="write textures and zone masks as PNGs")
    p.add_argument("--export", metavar="GLB", help="write the avatar as binary glTF (a .glb file)")
    p.add_argument("--save", metavar="NPZ", help="write the FaceRig file")
    p.add_argument("--export-arkit", metavar="GLB",
                   help="write the avatar as a third-party ARKit character would come: head, eyes and teeth "
                        "as separate meshes with ARKit-named morphs only, no face bones, no mapping")
    p.add_argument("--naming", default=None, choices=["arkit", "_L", ".L", "Left_", "blendShape1."],
                   help="--export-arkit: morph naming (eyeBlinkLeft, eyeBlink_L, eyeBlink.L, EyeBlink_Left, "
                        "blendShape1.eyeBlinkLeft; default _L)")
    p.add_argument("--quantize", action="store_true", help="--export-arkit: KHR_mesh_quantization (int16)")
    p.add_argument("--skeleton", action="store_true", help="--export-arkit: a Hips-Neck-Head skin")
    p.add_argument("--body", action="store_true", help="--export-arkit: a textured body under the head")
    p.add_argument("--variant", default=None, help="a built-in variant, e.g. 'wide'")
    p.set_defaults(func=_cmd_avatar)


def _add_synth_parser(sub, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("synth", parents=[common], help="render a synthetic performance with ground truth")
    p.add_argument("-o", "--output", required=True, metavar="MP4",
                   help="the clip to write (its ground truth goes beside it as .truth.npz)")
    p.add_argument("--frames", type=int, default=150, help="frames to render (default: 150)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the performance (default: 0)")
    p.add_argument("--size", type=int, default=512, help="frame size in pixels, square (default: 512)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate (default: 30)")
    p.add_argument("--no-head-motion", action="store_true", help="keep the head still")
    p.add_argument("--no-expression", action="store_true", help="fixed expression, head motion only")
    p.add_argument("--face-exit", action="store_true", help="the face leaves the frame for a while")
    p.add_argument("--variant", default=None, help="render a built-in avatar variant")
    p.add_argument("--actor", metavar="CHARACTER", default=None,
                   help="render this ARKit character (.glb/.gltf/.npz) through a random ARKit performance "
                        "instead of the default avatar ('default': the default avatar's own performance)")
    p.add_argument("--rom", action="store_true",
                   help="with --actor: perform the range-of-motion protocol (docs/calibration.md) instead "
                        "(--frames: the protocol's length)")
    _add_start_option(p)
    p.set_defaults(func=_cmd_synth)


def _add_start_option(p) -> None:
    p.add_argument("--start", choices=STARTS, default="rest",
                   help="rest: start on the neutral; held: one expression held for the first seconds; raised: "
                        "brows raised on most frames (both take the neutral mid-clip) (default: rest)")


def _add_track_parser(sub, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("track", parents=[common], help="track a clip's face into track.npz")
    p.add_argument("clip", help="the video to track")
    p.add_argument("-o", "--output", required=True, metavar="NPZ", help="the track file to write")
    p.add_argument("--overlay", metavar="MP4", help="also write the source with landmarks drawn")
    _add_neutral_options(p)
    _add_face_model_option(p)
    _add_face_choice_options(p)
    p.set_defaults(func=_cmd_track)


def _add_calibrate_parser(sub, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("calibrate", parents=[common],
                       help="learn an actor's calibration from a range-of-motion take into actor.json")
    p.add_argument("takes", nargs="+", metavar="TAKE",
                   help="the range-of-motion take (docs/calibration.md); several takes of the actor calibrate "
                        "together (the curves are the mean of each take's)")
    p.add_argument("-o", "--output", required=True, metavar="JSON",
                   help="the calibration to write (readable and editable; give it to --calibration)")
    _add_face_model_option(p)
    _add_face_choice_options(p)
    p.set_defaults(func=_cmd_calibrate)


def _add_run_parser(sub, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("run", parents=[common], help="clip -> animated, wrinkled character (video + exports)")
    p.add_argument("clip", help="the video of a face")
    p.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="output folder: the results go to DIR/<clip stem>/ (or DIR/NAME/ with --name)")
    p.add_argument("--name", metavar="NAME", default=None,
                   help="the results' folder name under DIR (default: the clip's stem); two clips of "
                        "the same name from different folders need different names")
    _add_neutral_options(p)
    _add_run_options(p)
    p.set_defaults(func=_cmd_run)


def _add_eval_parser(sub, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("eval", parents=[common], help="accuracy: synthetic ground truth, or fidelity on real clips")
    evals = p.add_subparsers(dest="dataset", required=True, metavar="DATASET")
    _add_eval_synthetic_parser(evals, common)
    _add_eval_fidelity_parser(evals, common)
    _add_eval_shading_parser(evals, common)
    _add_eval_characters_parser(evals, common)


def _add_eval_synthetic_parser(evals, common: argparse.ArgumentParser) -> None:
    p = evals.add_parser("synthetic", parents=[common], help="closed-loop accuracy against synthetic ground truth")
    p.add_argument("--frames", type=int, default=300, help="frames of the synthetic clip (default: 300)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the performance (default: 0)")
    p.add_argument("--size", type=int, default=512, help="frame size in pixels (default: 512)")
    p.add_argument("--target-variant", default=None, help="retarget onto another avatar, e.g. 'wide'")
    p.add_argument("--actor", metavar="CHARACTER", default=None,
                   help="render this ARKit character as the actor ('default': the default avatar); "
                        "figures: ARKit curves and fidelity measures against its truth")
    p.add_argument("--target", metavar="CHARACTER", default=None,
                   help="with --actor: retarget onto this character ('default', the default: the default avatar)")
    p.add_argument("--calibration", action="store_true",
                   help="with --actor: also render the actor's range-of-motion take, calibrate on it and judge "
                        "the performance calibrated (docs/calibration.md)")
    p.add_argument("--json", metavar="PATH", help="also write the figures as JSON")
    _add_start_option(p)
    p.set_defaults(func=_cmd_eval)


def _add_eval_fidelity_parser(evals, common: argparse.ArgumentParser) -> None:
    p = evals.add_parser("fidelity", parents=[common],
                         help="does the character do what the actor does? (real clips, no truth)")
    p.add_argument("paths", nargs="+", metavar="CLIP_OR_RUN_DIR",
                   help="clips (tracked and retargeted, nothing rendered) or `run` output folders")
    p.add_argument("--character", metavar="FILE", default=None, help="character for clips (default avatar)")
    p.add_argument("--plots", metavar="DIR", default=None,
                   help="write <clip>.fidelity.png per clip: each measure over time")
    p.add_argument("--json", metavar="PATH", help="write every figure as JSON")
    p.set_defaults(func=_cmd_eval_fidelity)


def _add_eval_shading_parser(evals, common: argparse.ArgumentParser) -> None:
    p = evals.add_parser("shading", parents=[common],
                         help="does the rendered character shade right? (tracks a run's avatar.mp4)")
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="`run` output folders (avatar.mp4 and track.npz)")
    p.add_argument("--json", metavar="PATH", help="write every figure as JSON")
    p.set_defaults(func=_cmd_eval_shading)


def _add_eval_characters_parser(evals, common: argparse.ArgumentParser) -> None:
    p = evals.add_parser("characters", parents=[common],
                         help="a gallery: each character performing a real clip, a contact sheet and its figures")
    p.add_argument("characters", nargs="*", metavar="FILE",
                   help="characters (.glb, .vrm, FaceRig .npz, a built-in name; default: the default avatar)")
    p.add_argument("--clip", default=None,
                   help="the clip they perform (default: ../shared/clips/d12.mp4 beside the repository, "
                        "else sample_videos/sample.mp4)")
    p.add_argument("-o", "--output", default="gallery", metavar="DIR",
                   help="writes DIR/<name>.png (the sheet) and DIR/<name>/ (avatar.mp4, animation.glb, ...); "
                        "default: gallery")
    p.add_argument("--size", type=int, default=256, help="render size in pixels (default: 256)")
    p.add_argument("--cell", type=int, default=192, help="sheet cell size in pixels (default: 192)")
    p.add_argument("--track", metavar="TRACK_NPZ", default=None,
                   help="the clip's track.npz (e.g. a run's) instead of tracking the clip again")
    p.add_argument("--json", metavar="PATH", help="write every figure as JSON")
    p.set_defaults(func=_cmd_eval_characters)


def _add_batch_parser(sub, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("batch", parents=[common], help="run many clips in parallel")
    p.add_argument("inputs", nargs="+", help="clips, folders or glob patterns")
    p.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="output folder: each clip goes to DIR/<clip stem>/, the report to "
                        "DIR/batch_report.json")
    p.add_argument("--jobs", type=int, default=None,
                   help="parallel clips, 1 or more (default: the cores this process may use)")
    p.add_argument("--resume", action="store_true",
                   help="skip clips whose outputs are complete and made with the same options "
                        "from the same clip and character content")
    p.add_argument("--ray", metavar="ADDRESS", default=None,
                   help="distribute over a Ray cluster: local, auto (this machine's cluster), "
                        "HOST:PORT or ray://HOST:PORT")
    _add_calibration_option(p, batch=True)
    _add_run_options(p)
    p.set_defaults(func=_cmd_batch)


def _add_bench_parser(sub, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("bench", parents=[common], help="measure each stage and the whole pipeline")
    p.add_argument("--size", type=int, default=512, help="frame size in pixels (default: 512)")
    p.add_argument("--frames", type=int, default=300, help="frames of the synthetic clip (default: 300)")
    p.add_argument("--json", metavar="PATH", help="also write the figures as JSON")
    p.add_argument("--memory-seconds", type=float, default=0, metavar="S",
                   help="instead: peak memory of a run on an S-second clip vs a 10-second one")
    p.add_argument("--calibration", action="store_true",
                   help="instead: how long `calibrate` takes on a synthetic range-of-motion take")
    p.set_defaults(func=_cmd_bench)


def build_parser() -> argparse.ArgumentParser:
    """The ``capture2face`` parser: the global flags, then one subparser per command."""
    parser = argparse.ArgumentParser(
        prog="capture2face",
        description="Performance capture: a face video drives a wrinkled 3D character.",
    )
    common = _common_options()
    parser.add_argument("--debug", action="store_true", default=False, help="show tracebacks on errors")
    parser.add_argument("-q", "--quiet", action="store_true", default=False, help="no progress bars")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    # The order here is the order `capture2face --help` lists the commands in.
    _add_avatar_parser(sub, common)
    _add_synth_parser(sub, common)
    _add_track_parser(sub, common)
    _add_calibrate_parser(sub, common)
    _add_run_parser(sub, common)
    _add_eval_parser(sub, common)
    _add_batch_parser(sub, common)
    _add_bench_parser(sub, common)
    return parser


def os_error_line(exc: OSError) -> str:
    """``<path>: No space left on device``: an OSError as one line."""
    text = exc.strerror or str(exc) or exc.__class__.__name__
    paths = [str(f) for f in (exc.filename, exc.filename2) if f is not None]
    line = f"{' -> '.join(paths)}: {text}" if paths else text
    return " ".join(line.split())


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    install_process_defaults()
    warnings_to_stderr()  # a warning no report carries: `capture2face: warning: ...`
    readable_streams()  # a file name that is not UTF-8 prints as \xNN, never fails a command
    if argv is None:  # the process is the command (not a caller's main(args))
        defer_pyplot()  # it imports MediaPipe, never matplotlib
    try:
        if getattr(args, "json", None):  # before the evaluation, not after it
            check_output_file(args.json, "--json")
        return int(args.func(args) or 0)
    except CaptureError as exc:
        if args.debug:
            raise
        print(f"capture2face: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except OSError as exc:  # a full disk, a permission lost mid-run: staged outputs are gone
        if args.debug:
            raise
        print(f"capture2face: error: {os_error_line(exc)}", file=sys.stderr)
        return CaptureError.exit_code
    except KeyboardInterrupt:
        if args.debug:
            raise
        print("capture2face: interrupted", file=sys.stderr)
        if argv is None:
            exit_interrupted()
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
