#pragma once
// The studio's open document: the project, the artist's work on it (focus keyframes, atlas
// edits), whether it changed since the last save, the undo history of the focus track,
// autosave and the recent-files list.
// Saved work lives in the project folder (project.json "focus" section, edits/); autosave
// writes to <project>/.autosave/ and never touches the saved files, so a crash or "Discard"
// cannot lose what was saved, and a crash after a change can be recovered on the next open.
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "edit/atlas_edit.h"
#include "edit/focus.h"
#include "project/project.h"

namespace refocus {

class StudioDoc {
  public:
    bool is_open() const { return m_project != nullptr; }
    const Project& project() const { return *m_project; }
    Project& project() { return *m_project; }
    FocusTrack& focus() { return m_focus; }
    ProjectEdits& edits() { return m_edits; }

    // Opens a project folder (or its project.json). Throws refocus::Error naming the file.
    void open(const std::string& path);
    // Ingests `clip` into a new project at `dir` and opens it.
    void create(const std::string& clip, const std::string& dir);
    void close();

    // Writes project.json ("focus", "edits") and edits/ atomically; clears the autosave.
    void save();
    // Copies the project folder to `dir` (must not exist or be empty), then saves there.
    void save_as(const std::string& dir);
    // The same in three steps, so that the copy (the frame cache: gigabytes for a long clip)
    // runs off the UI thread: check the target on the UI thread (returns its absolute path),
    // copy anywhere (touches no document state; `progress(done, total)` returning false
    // cancels), finish on the UI thread (points the document at the copy, saves the work there).
    fs::path save_as_target(const std::string& dir) const;
    static void copy_project_files(const fs::path& from, const fs::path& to,
                                   const std::function<bool(int, int)>& progress = {});
    void finish_save_as(const fs::path& to);

    bool dirty() const { return m_dirty; }
    void mark_dirty();
    // Writes .autosave/ when the document changed since the last save or autosave and
    // `interval_s` passed since the change. Returns true when it wrote.
    bool autosave_if_due(double now_s, double interval_s = 60.0);
    // The same in two halves, so that the writing runs off the UI thread: when an autosave is
    // due, takes a snapshot of the work (focus keys, edit layers) and returns the function that
    // writes it (it touches no document state); else returns an empty function.
    std::function<void()> take_autosave(double now_s, double interval_s = 60.0);
    // Found when the project was opened: an autosave whose work (focus keys, edits) differs
    // from the saved work, whatever the file times (a running fit rewrites project.json).
    bool has_newer_autosave() const;
    void restore_autosave();  // takes the autosaved focus and edits (document dirty)
    void discard_autosave();

    static fs::path autosave_dir(const fs::path& project_dir);

    // Undo for the focus track (keys, easing, the tracked point): the track as it was before
    // each finished change, with a label. Change focus() freely, then commit(label) when the
    // gesture ends (a drag: on release), so that one gesture is one entry. Atlas strokes keep
    // their own undo (AtlasEditor). Saving keeps the history; opening or restoring starts anew.
    bool commit(const std::string& label);  // false when the track did not change
    bool undo();  // commits a change in progress first; false when there is nothing to undo
    bool redo();
    bool can_undo() const { return !m_undo.empty(); }
    bool can_redo() const { return !m_redo.empty(); }
    std::string undo_label() const { return m_undo.empty() ? "" : m_undo.back().label; }
    std::string redo_label() const { return m_redo.empty() ? "" : m_redo.back().label; }

  private:
    struct UndoEntry {
        FocusTrack track;  // undo stack: before the change; redo stack: after it
        std::string label;
    };
    static constexpr size_t kUndoLimit = 500;

    void load_work(const Project& from, const fs::path& edits_dir_project);
    void write_work(Project& to);
    bool autosave_differs() const;
    void step_history(std::vector<UndoEntry>& from, std::vector<UndoEntry>& to);

    std::unique_ptr<Project> m_project;
    FocusTrack m_focus;
    ProjectEdits m_edits;
    bool m_dirty = false;
    bool m_autosaved = true;
    double m_changed_at = 0.0;
    bool m_newer_autosave = false;
    std::vector<UndoEntry> m_undo, m_redo;
    FocusTrack m_committed;  // the track as of the last commit, undo or redo
};

// Recent projects, newest first, in $XDG_CONFIG_HOME/refocus/recent.json (or ~/.config/...).
std::vector<std::string> recent_projects();
void add_recent_project(const std::string& dir);

}  // namespace refocus
