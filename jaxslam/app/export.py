"""``jaxslam export-bag``: write a laser log (a dataset name, a CARMEN log path or the
laser simulator) as a ROS 1 bag or a ROS 2 bag, in the conventions that
``jaxslam run --dataset BAG`` reads (:func:`jaxslam.datasets.rosbag_write.write_rosbag`:
``/scan``, ``/odom`` or ``/tf``, the laser mount on ``/tf_static``).

For trying the bag path of ``jaxslam run`` without a robot, and for handing a CARMEN
log to ROS tools (``rosbag play``, ``ros2 bag play``, RViz) with no ROS installation
needed to write it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


DESCRIPTION = """\
Write a laser log (a dataset name, a CARMEN log path or the laser simulator) as a
ROS 1 or ROS 2 bag, in the conventions `jaxslam run --dataset BAG` reads:
sensor_msgs/LaserScan on /scan, nav_msgs/Odometry on /odom (or odom -> base_link
on /tf), the laser mount on /tf_static.
"""


def add_parser(sub, positive_int, nonneg_int) -> None:
    ex = sub.add_parser(
        "export-bag",
        help="write a laser log (dataset name or CARMEN log path) as a ROS 1 or ROS 2 bag",
        description=DESCRIPTION,
    )
    ex.add_argument("--dataset", required=True,
                    help="laser dataset name (see `jaxslam datasets`) or a path to a CARMEN log")
    ex.add_argument("--out", type=Path, required=True, metavar="BAG",
                    help="the bag to write (must not exist): NAME.bag is a ROS 1 bag, any other name a ROS 2 "
                         "bag folder")
    ex.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3",
                    help="ROS 2 bags: the storage format")
    ex.add_argument("--odometry", choices=("topic", "tf"), default="topic",
                    help="odometry as nav_msgs/Odometry on /odom (topic) or as odom -> base_link on /tf (tf)")
    ex.add_argument("--max-scans", type=positive_int, default=None, metavar="N",
                    help="write the first N scans only; default: all")
    ex.add_argument("--seed", type=nonneg_int, default=0, help="the simulator's world (sim-laser)")


def run(args) -> dict[str, Any]:
    """Write the bag; what was written (path, ROS version, storage, topics, scans, span)."""
    from jaxslam.app.errors import RunError
    from jaxslam.app.data import is_bag, load_log, resolve_dataset
    from jaxslam.datasets.rosbag_write import write_rosbag

    info, path, kind = resolve_dataset(args.dataset, None)
    if kind != "laser" or (path is not None and is_bag(path)):
        raise RunError(f"--dataset {args.dataset!r}: export-bag writes laser logs (a laser dataset name or a "
                       f"CARMEN log); this is {'a ROS bag already' if kind == 'laser' else f'{kind} data'}")
    out = Path(args.out)
    if out.exists():
        raise RunError(f"--out {str(out)!r} already exists; give a new name")
    log, _ = load_log(info, path, args.seed, None, None)
    scans = min(log.num_scans, args.max_scans or log.num_scans)
    version = 1 if out.suffix == ".bag" else 2
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        write_rosbag(log, out, version=version, storage=args.storage, odometry=args.odometry,
                     scans=slice(0, scans))
    except ValueError as err:  # a log with interleaved beam geometries
        raise RunError(f"--dataset {args.dataset!r}: {err}") from None
    times = log.scan_times[:scans]
    return {"path": str(out), "ros": version, "storage": None if version == 1 else args.storage,
            "dataset": info.name if info is not None else str(path), "scans": scans,
            "topics": ["/scan", "/odom" if args.odometry == "topic" else "/tf", "/tf_static"],
            "span_s": float(times[-1] - times[0]) if scans else 0.0}


def report(result: dict[str, Any]) -> str:
    """One line: what was written where."""
    kind = "ROS 1 bag" if result["ros"] == 1 else f"ROS 2 bag ({result['storage']})"
    return (f"wrote {result['path']}: {kind}, {result['scans']} scans of {result['dataset']} over "
            f"{result['span_s']:.1f} s on {', '.join(result['topics'])}; "
            f"jaxslam run --dataset {result['path']} --out DIR maps it")
