#pragma once
// Scripted sessions (refocus-studio --script file.json): a JSON list of actions run one after
// another through the studio's own action methods, each waiting until its work is finished (a
// fit, an export, a frame's render). CI drives the studio with it under Xvfb
// (tests/gui/smoke.json); a failing step exits non-zero naming the step.
//   {"open": path}                         {"new": {"clip": c, "project": dir}}
//   {"fit": {"preset": p, "iters": n | "minutes": m, "resume": b}}
//   {"wait_depth": true}                   {"frame": n}          {"mode": "refocused"}
//   {"key": {"lane": l, "frame": n, "value": v,
//            "easing": "linear|ease|ease_in|ease_out|hold"}}
//   {"move_key": {"lane": l, "from": a, "to": b}}   {"delete_key": {"lane": l, "frame": n}}
//   {"undo": true}  {"redo": true}  (the document's focus changes; fails when there is none)
//   {"focus_click": {"frame": n, "x": x, "y": y}}   {"track_click": {...same...}}
//   {"paint": {"layer": "bg|fg", "points": [[x, y], ...], "color": [r, g, b], "size": s,
//              "hardness": h, "opacity": o}}        (atlas px, linear colour)
//   {"export": {"what": [...], "format": f, "out": dir, "first": a, "last": b}}
//   {"atlas_view": true|false}  {"split": {"left": mode, "right": mode, "wipe": 0..1}}
//   {"time_slice": {"row": y, "save": "slice.png"}}  (shows the slice of the current view, waits
//   for it; "save" writes it, x → column, y → frame)   {"time_slice": false}  (hides it)
//   {"save": true}  {"save_as": dir}  {"reopen": true}  {"screenshot": path}
//   {"expect": {"keys": {"focus": n, ...}, "edits": true|false, "fitted": true, "dirty": b,
//               "undo": label, "redo": label, "key_frames": {"focus": [frames]},
//               "easing": {"focus": ["linear", ...]}}}
//   {"stats": path}  (UI frame times as JSON; prints "longest UI frame: <ms> ms")
//   {"play": {"from": n, "frames": n, "cache": true, "min_distinct": n}}  (prints "playback:
//   <distinct> distinct frames of <shown>")   {"window_size": [w, h]}
//   {"layout": {"side_width": w, "timeline_height": h}}   {"autosave": true}  {"touch": path}
//   {"wait_fitting": step}  {"restore_autosave": true}  {"crash": true} (SIGKILL, as kill -9)
//   {"fit": {..., "wait": false}} starts the fit and goes on   {"proxy": "auto|full|half|quarter"}
//   {"preview_renderer": "auto|gpu|cpu"}   {"preview_quality": "fast|exact"}  (View menu)
//   {"expect": {..., "autosave_offered": b, "modified": b}}   {"quit": true}
//   {"drop": path}  (as if dropped on the window: opens it like File > Open; waits for it)
//   {"browser": {"dialog": "open|new|new_folder|save_as|atlas_export|atlas_import", "dir": d,
//                "shows": [name, ...], "select": name, "pick": name}}  (opens that file browser
//   on d; "shows" must be listed; "select" clicks a name; "pick" double-clicks it (open
//   dialogs) or types it as the name and presses the button (folder, save), then waits for
//   what follows: a folder entered, a project opened, an atlas written)
//   {"browser": false}  (closes it)
#include <nlohmann/json.hpp>

#include <optional>
#include <string>

namespace refocus {

class Studio;

class StudioScript {
  public:
    explicit StudioScript(const std::string& path);
    // Runs or continues the current step after a drawn frame. -1: keep going; 0: finished;
    // 1: failed (the reason is printed on stderr).
    int advance(Studio& studio);

  private:
    bool run_step(Studio& studio, const nlohmann::json& step);  // true: step finished
    // One group of steps each: nullopt for a step of another group, else whether it finished.
    std::optional<bool> project_step(Studio& st, const nlohmann::json& step, bool first);
    std::optional<bool> view_step(Studio& st, const nlohmann::json& step, bool first);
    std::optional<bool> edit_step(Studio& st, const nlohmann::json& step, bool first);
    std::optional<bool> check_step(Studio& st, const nlohmann::json& step, bool first);
    bool play_step(Studio& st, const nlohmann::json& play, bool first);
    std::optional<bool> file_step(Studio& st, const nlohmann::json& step, bool first);
    bool worker_idle(Studio& st) const;  // throws the fit's error when it failed
    std::string m_path;
    nlohmann::json m_steps;
    size_t m_index = 0;
    bool m_started = false;
    double m_step_start = 0.0;
    int m_settle = 0;
    bool m_play_started = false;
    double m_step_clock = 0.0;
};

}  // namespace refocus
