"""Replies of the UR Dashboard Server (e-Series, port 29999) for the controller emulator.

Commands and reply texts from Universal Robots' "Dashboard Server e-Series, port 29999"
command table: one command per line (terminated by ``\\n``), one reply line each.
"""

from __future__ import annotations

from sim.emulators.ur.controller import (
    ROBOT_MODES,
    RUNTIME_STATES,
    SAFETY_MODES,
    UNLOCK_REFUSED,
    URController,
    mode_name,
)

GREETING = "Connected: Universal Robots Dashboard Server"


def reply(robot: URController, line: str) -> str:
    """The dashboard server's answer to one command line (without the line end)."""
    command = line.strip()
    word = command.lower()
    with robot.lock:
        if word == "robotmode":
            return f"Robotmode: {mode_name(ROBOT_MODES, robot.robot_mode)}"
        if word == "safetymode":
            return f"Safetymode: {mode_name(SAFETY_MODES, robot.safety_mode)}"
        if word == "safetystatus":
            return f"Safetystatus: {mode_name(SAFETY_MODES, robot.safety_mode)}"
        if word == "polyscopeversion":
            major, minor, bugfix, build = robot.version
            return f"URSoftware {major}.{minor}.{bugfix}.{build} (Sep 23 2022)"
        if word == "get robot model":
            return "UR5"
        if word == "get serial number":
            return robot.serial_number
        if word == "is in remote control":
            return "true" if robot.remote_control else "false"
        if word == "power on":
            robot.power_on()
            return "Powering on"
        if word == "power off":
            robot.power_off()
            return "Powering off"
        if word == "brake release":
            robot.brake_release()
            return "Brake releasing"
        if word == "unlock protective stop":
            return "Protective stop releasing" if robot.unlock_protective_stop() else UNLOCK_REFUSED
        if word == "close safety popup":
            robot.safety_popup = False
            return "closing safety popup"
        if word == "close popup":
            return "closing popup"
        if word.startswith("popup "):
            return "showing popup"
        if word == "restart safety":
            return "Restarting safety"
        if word.startswith("load "):
            name = command[5:].strip()
            if name not in robot.programs:
                return f"File not found: {name}"
            robot.loaded_program = name
            return f"Loading program: {name}"
        if word == "get loaded program":
            return f"Loaded program: {robot.loaded_program}" if robot.loaded_program else "No program loaded"
        if word == "play":
            return "Starting program" if robot.play() else "Failed to execute: play"
        if word == "stop":
            return "Stopped" if robot.stop_program() else "Failed to execute: stop"
        if word == "pause":
            return "Pausing program" if robot.pause() else "Failed to execute: pause"
        if word == "running":
            return f"Program running: {str(robot.runtime_state == RUNTIME_STATES['PLAYING']).lower()}"
        if word == "programstate":
            name = robot.loaded_program or "<unnamed>"
            return f"{mode_name(RUNTIME_STATES, robot.runtime_state)} {name}"
        if word == "quit":
            return "Disconnected"
    return f"could not understand: '{command}'"
