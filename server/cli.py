"""`fpv-station`: the command line.

    fpv-station serve [--source CONN] [--host H] [--port P] [--config FILE.toml] ...
    fpv-station config --dump [the same flags]   # every setting, as commented TOML

Each subcommand registers its flags in its own `add_*_parser` function; flags map onto
dotted settings keys so that the CLI is the last layer over TOML and environment.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

from fpv_station.server.settings import Settings, SettingsError, load_settings


def add_serve_parser(sub: Any) -> None:
    p = sub.add_parser("serve", help="run the ground station (web UI, telemetry, video, recording)")
    add_station_flags(p)
    p.set_defaults(func=run_serve)


def add_config_parser(sub: Any) -> None:
    p = sub.add_parser(
        "config", help="print the settings `serve` would run with, as commented TOML (--dump)"
    )
    p.add_argument(
        "--dump",
        action="store_true",
        help="print every setting with its description; takes serve's flags",
    )
    add_station_flags(p)
    p.set_defaults(func=run_config)


def run_config(args: argparse.Namespace) -> int:
    from fpv_station.server.settings_dump import dump_settings

    if not args.dump:
        print("fpv-station config: --dump prints the effective settings", file=sys.stderr)
        return 2
    print(dump_settings(settings_from_args(args)), end="")
    return 0


def add_station_flags(p: argparse.ArgumentParser) -> None:
    """The station's settings flags, shared by `serve` and `config --dump`."""
    p.add_argument("--config", type=Path, help="TOML settings file")
    p.add_argument("--host", dest="server.host", help="address to listen on (default 0.0.0.0)")
    p.add_argument("--port", dest="server.port", type=int, help="HTTP port (default 8000)")
    p.add_argument("--token", dest="server.token", help="token that guards control endpoints")
    p.add_argument(
        "--open",
        dest="server.control",
        action="store_const",
        const="open",
        help="no control token: anyone who reaches the station may control it",
    )
    p.add_argument(
        "--source",
        dest="link.source",
        help="MAVLink source: sim, /dev/serial0:921600, /dev/ttyACM0, udpin:0.0.0.0:14550, "
        "udpout:HOST:PORT, tcp:HOST:PORT, replay:FILE.tlog[?speed=N]",
    )
    p.add_argument("--sysid", dest="link.sysid", type=int, help="follow this autopilot system id")
    p.add_argument(
        "--forward",
        dest="link.forward",
        action="append",
        help="also copy raw MAVLink to this connection (udpout:HOST:PORT), repeatable",
    )
    p.add_argument("--link-lost-s", dest="link.link_lost_s", type=float)
    p.add_argument(
        "--udpin-any-sender",
        dest="link.udpin_lock",
        action="store_const",
        const=False,
        help="udpin: hear every host and answer the last (default: only the first host)",
    )
    add_signing_flag(p)
    add_camera_flags(p)
    add_viser_flags(p)
    add_recording_flags(p)


def add_recording_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--sessions-dir",
        dest="recording.sessions_dir",
        type=Path,
        help="where recorded sessions go (default ./sessions)",
    )
    p.add_argument(
        "--record-rate",
        dest="recording.rate_hz",
        type=float,
        help="telemetry.csv rows per second (1-100, default 30)",
    )
    p.add_argument(
        "--no-auto-record",
        dest="recording.auto_record_on_arm",
        action="store_const",
        const=False,
        help="do not start recording when the vehicle arms",
    )


def add_viser_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--viser-port",
        dest="viser.port",
        type=int,
        help="port of the 3D trajectory panel (viser; default 8080)",
    )
    p.add_argument(
        "--viser-replay-port",
        dest="viser.replay_port",
        type=int,
        help="port of the replay page's 3D panel (viser; default: --viser-port + 1)",
    )
    p.add_argument(
        "--no-3d",
        dest="viser.enabled",
        action="store_const",
        const=False,
        help="do not start the 3D trajectory panel",
    )


def add_sim_parser(sub: Any) -> None:
    p = sub.add_parser("sim", help="run the digital twin alone, as a MAVLink vehicle")
    p.add_argument("--config", type=Path, help="TOML settings file")
    p.add_argument(
        "--mavlink",
        default="udpout:127.0.0.1:14550",
        help="where the twin talks MAVLink: udpout:HOST:PORT (to a ground station, default "
        "udpout:127.0.0.1:14550) or udpin:HOST:PORT (wait for one)",
    )
    p.add_argument("--scene", dest="twin.scene", type=Path, help="scene TOML (default: the field)")
    p.add_argument("--seed", dest="twin.seed", type=int)
    p.add_argument("--speed", dest="twin.realtime_factor", type=float, help="real-time factor")
    p.add_argument("--wind", dest="twin.wind_east_mps", type=float, help="east wind (m/s)")
    p.add_argument("--gusts", dest="twin.gust_std_mps", type=float, help="gust std (m/s)")
    p.add_argument(
        "--turbulence", dest="twin.turbulence_std_mps", type=float, help="turbulence std (m/s)"
    )
    add_signing_flag(p)
    p.set_defaults(func=run_sim)


def add_signing_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--signing-key",
        dest="link.signing_key_file",
        type=Path,
        help="MAVLink 2 signing: a file (chmod 600) holding the passphrase given to "
        "MAVProxy's 'signing setup'; unsigned packets are then refused",
    )


def run_sim(args: argparse.Namespace) -> int:
    import signal
    import threading

    from fpv_station.core.scene import SceneError
    from fpv_station.twin.runner import twin_from_settings

    settings = settings_from_args(args)
    try:
        twin = twin_from_settings(settings.twin, args.mavlink, settings.link.signing_key())
        twin.start()
    except (SceneError, ValueError, OSError) as exc:
        print(f"fpv-station sim: {exc}", file=sys.stderr)
        return 2
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    print(
        f"fpv-station sim: twin '{twin.scene.name}' talking MAVLink on {args.mavlink}", flush=True
    )
    try:
        while not done.wait(1.0):
            if twin.error:
                print(f"fpv-station sim: twin died: {twin.error}", file=sys.stderr)
                return 1
    finally:
        twin.stop()
    return 0


def add_analyze_parser(sub: Any) -> None:
    from fpv_station.analysis import cli as analysis_cli

    p = sub.add_parser(
        "analyze",
        help="the paper's task metrics, table and plots for sessions, zips or .tlogs",
        description=analysis_cli.__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    analysis_cli.add_arguments(p)
    p.set_defaults(func=analysis_cli.run)


def add_learn_parsers(sub: Any) -> None:
    """export / demos: need the `learn` extra only when run (imports are in the commands)."""
    from fpv_station.learn import cli as learn_cli

    p = sub.add_parser(
        "export",
        help="sessions, zips or .tlogs to LeRobot, Minari or MCAP (one episode per flight)",
        description=learn_cli.__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    learn_cli.add_export_arguments(p)
    p.set_defaults(func=learn_cli.run_export)
    p = sub.add_parser("demos", help="fly the twin's scripted pilot K times into ordinary sessions")
    learn_cli.add_demos_arguments(p)
    p.set_defaults(func=learn_cli.run_demos)
    p = sub.add_parser("learn", help="behaviour cloning: train (bc) and fly in the twin (eval)")
    learn_cli.add_learn_arguments(p)


def add_camera_flags(p: Any) -> None:
    specs = "v4l2:/dev/video0[?width=640&height=480&fps=30&fourcc=MJPG], v4l2:0, file:X.mp4, "
    specs += "folder:DIR, sim:front, airsim:HOST:PORT/CAMERA, none"
    p.add_argument("--front", dest="cameras.front.spec", help=f"front camera: {specs}")
    p.add_argument("--bottom", dest="cameras.bottom.spec", help="bottom camera (same specs)")


def add_cameras_parser(sub: Any) -> None:
    p = sub.add_parser("cameras", help="list V4L2 video devices and their formats")
    p.set_defaults(func=run_cameras)


def run_cameras(args: argparse.Namespace) -> int:
    from fpv_station.companion.cameras.devices import format_devices, list_devices

    print(format_devices(list_devices()))
    return 0


def add_doctor_parser(sub: Any) -> None:
    p = sub.add_parser("doctor", help="check the wiring, cameras, disk, clock and ports")
    p.add_argument("--config", type=Path, help="TOML settings file")
    p.add_argument("--source", dest="link.source", help="MAVLink source to listen on")
    p.add_argument("--heartbeat-s", type=float, default=5.0, help="wait this long for one")
    add_camera_flags(p)
    add_viser_flags(p)
    p.add_argument("--port", dest="server.port", type=int, help="the web port to check")
    p.add_argument("--sessions-dir", dest="recording.sessions_dir", type=Path)
    p.set_defaults(func=run_doctor)


def run_doctor(args: argparse.Namespace) -> int:
    from fpv_station.server.doctor import format_table, run_checks

    settings = settings_from_args(args)
    check_link_settings(settings)  # a malformed source is an error to say, not a traceback
    checks = run_checks(settings, heartbeat_s=args.heartbeat_s)
    print(format_table(checks))
    failed = [c.name for c in checks if c.status == "FAIL"]
    print(f"\n{len(failed)} failed: {', '.join(failed)}" if failed else "\nall checks passed")
    return 1 if failed else 0


def add_install_service_parser(sub: Any) -> None:
    p = sub.add_parser(
        "install-service",
        help="install and start the systemd service (as root), or print it with --dry-run",
    )
    p.add_argument("--user", default=None, help="the user it runs as (default fpv-station)")
    p.add_argument("--dry-run", action="store_true", help="print the files and commands only")
    p.set_defaults(func=run_install_service)


def run_install_service(args: argparse.Namespace) -> int:
    from fpv_station.server.install_service import (
        DEFAULT_USER,
        ServicePlan,
        install,
        installed_exec_path,
    )

    plan = ServicePlan(user=args.user or DEFAULT_USER, exec_path=installed_exec_path())
    return install(plan, dry_run=args.dry_run)


def settings_from_args(args: argparse.Namespace) -> Settings:
    overrides = {k: v for k, v in vars(args).items() if "." in k}
    return load_settings(getattr(args, "config", None), overrides)


def run_serve(args: argparse.Namespace) -> int:
    from fpv_station.server.app import create_app
    from fpv_station.server.listen import listening_socket, uvicorn_server

    settings = settings_from_args(args)
    check_link_settings(settings)
    srv = settings.server
    token_from = "server.token (--token)"
    if srv.control == "token" and not srv.token:
        from fpv_station.server.token_file import default_token_file, load_or_create_token

        srv.token = load_or_create_token(srv.token_file)
        token_from = str(srv.token_file or default_token_file())
        print(f"fpv-station: control token in {token_from}")
    app = create_app(settings)
    url = f"http://{_display_host(srv.host)}:{srv.port}/"
    if srv.control == "token" and sys.stdout.isatty():
        # The page keeps the token and takes it out of the URL. Only on a terminal: a
        # log (the journal under systemd, a file) must not hold the token.
        url += f"?token={srv.token}"
    elif srv.control == "token":
        url += f" (add ?token=TOKEN once, TOKEN from {token_from})"
    else:
        print("fpv-station: control is OPEN (server.control = 'open'): anyone can fly it")
    print(f"fpv-station: open {url}")
    # Our own listening socket: it caps unsent bytes per connection (see server/listen.py).
    sock = listening_socket(srv.host, srv.port)
    uvicorn_server(app).run(sockets=[sock])
    return 0


def check_link_settings(settings: Settings) -> None:
    """Refuse unusable connection strings before the server starts, with a clear message."""
    from fpv_station.companion.stream_request import message_id
    from fpv_station.companion.transports import ConnectionStringError, parse_connection

    try:
        parse_connection(settings.link.source)
        for fwd in settings.link.forward:
            if parse_connection(fwd).kind not in ("udpin", "udpout"):
                raise ConnectionStringError(
                    f"--forward '{fwd}' must be udpout:HOST:PORT or udpin:HOST:PORT."
                )
        for name in settings.link.message_rates_hz:
            message_id(name)
    except ValueError as exc:
        raise SettingsError(str(exc)) from None


def _display_host(host: str) -> str:
    return "localhost" if host in ("0.0.0.0", "::", "") else host


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fpv-station", description=__doc__.split("\n")[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)
    add_serve_parser(sub)
    add_config_parser(sub)
    add_sim_parser(sub)
    add_analyze_parser(sub)
    add_learn_parsers(sub)
    add_cameras_parser(sub)
    add_install_service_parser(sub)
    add_doctor_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        return args.func(args)
    except SettingsError as exc:
        print(f"fpv-station: {exc}", file=sys.stderr)
        return 2
