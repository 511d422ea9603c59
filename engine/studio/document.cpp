#include "studio/document.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cstdlib>
#include <memory>

#include "util/error.h"
#include "util/fs.h"
#include "util/json_file.h"
#include "util/lock.h"

namespace refocus {

using nlohmann::json;

fs::path StudioDoc::autosave_dir(const fs::path& project_dir) {
    return project_dir / ".autosave";
}

void StudioDoc::load_work(const Project& from, const fs::path& edits_from) {
    const std::string label = from.project_file().string();
    m_focus = from.sections.contains("focus")
                  ? FocusTrack::from_json(from.sections.at("focus"), label)
                  : FocusTrack{};
    Project where = from;
    where.dir = edits_from;
    m_edits = ProjectEdits::load(where);
    m_undo.clear();
    m_redo.clear();
    m_committed = m_focus;
}

void StudioDoc::write_work(Project& to) {
    m_edits.save(to);  // the edit files and the "edits" section
    to.sections["focus"] = m_focus.to_json();
    to.save_merged({"focus", "edits"});  // "fit" is the fit thread's: keep its latest
}

void StudioDoc::open(const std::string& path) {
    auto p = std::make_unique<Project>(Project::load(path));
    StudioDoc next;
    next.load_work(*p, p->dir);
    next.m_project = std::move(p);
    next.m_newer_autosave = next.autosave_differs();
    *this = std::move(next);
    add_recent_project(m_project->dir.string());
}

void StudioDoc::create(const std::string& clip, const std::string& dir) {
    Project p = create_project(clip, dir, {});
    open(p.dir.string());
}

void StudioDoc::close() {
    *this = StudioDoc{};
}

void StudioDoc::save() {
    if (!m_project) throw Error("no project is open");
    // One writer per project: a CLI fit or atlas import running on it refuses this save.
    const auto lock = ProjectLock::acquire(m_project->dir, "refocus studio (save)");
    write_work(*m_project);
    discard_autosave();
    m_dirty = false;
    m_autosaved = true;
}

void StudioDoc::save_as(const std::string& dir) {
    const fs::path to = save_as_target(dir);
    copy_project_files(m_project->dir, to);
    finish_save_as(to);
}

fs::path StudioDoc::save_as_target(const std::string& dir) const {
    if (!m_project) throw Error("no project is open");
    if (dir.empty()) throw Error("give a folder to save the project in");
    const fs::path to = fs::absolute(dir).lexically_normal();
    std::error_code ec;
    if (fs::exists(to) && !fs::is_empty(to, ec))
        throw Error(file_error(to.string(), "exists and is not empty: choose a new folder"));
    const fs::path from = fs::absolute(m_project->dir).lexically_normal();
    const auto rel = to.lexically_relative(from);
    if (to == from || (!rel.empty() && *rel.begin() != ".."))
        throw Error(file_error(to.string(),
                               "is inside the project being saved: choose a folder outside it"));
    return to;
}

void StudioDoc::copy_project_files(const fs::path& from, const fs::path& to,
                                   const std::function<bool(int, int)>& progress) {
    std::error_code ec;
    fs::create_directories(to, ec);
    if (ec) throw Error(file_error(to.string(), "cannot create the folder: " + ec.message()));
    // Every file first (for the progress), the autosave left behind: it belongs to the original.
    std::vector<fs::path> files;
    for (auto it = fs::recursive_directory_iterator(from, ec);
         !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
        const fs::path rel = it->path().lexically_relative(from);
        if (*rel.begin() == ".autosave") {
            if (it->is_directory()) it.disable_recursion_pending();
            continue;
        }
        if (it->is_directory())
            fs::create_directories(to / rel);
        else
            files.push_back(rel);
    }
    if (ec) throw Error(file_error(from.string(), "cannot list the project: " + ec.message()));
    const int n = static_cast<int>(files.size());
    for (int i = 0; i < n; ++i) {
        if (progress && !progress(i, n))
            throw Error("save as cancelled; " + to.string() + " holds a partial copy");
        fs::copy_file(from / files[i], to / files[i], fs::copy_options::overwrite_existing, ec);
        if (ec) throw Error(file_error((to / files[i]).string(), "cannot copy: " + ec.message()));
    }
    if (progress) progress(n, n);
}

void StudioDoc::finish_save_as(const fs::path& to) {
    if (!m_project) throw Error("no project is open");
    // The source clip path is stored relative to the project: keep it pointing at the clip.
    Project moved = *m_project;
    if (!moved.source.empty() && fs::path(moved.source).is_relative())
        moved.source = fs::absolute(m_project->dir / moved.source).lexically_normal().string();
    moved.dir = to;
    *m_project = moved;
    save();
    add_recent_project(to.string());
}

void StudioDoc::mark_dirty() {
    m_dirty = true;
    m_autosaved = false;
    m_changed_at = 0.0;  // stamped by the next autosave_if_due
}

bool StudioDoc::autosave_if_due(double now_s, double interval_s) {
    auto job = take_autosave(now_s, interval_s);
    if (!job) return false;
    job();
    return true;
}

std::function<void()> StudioDoc::take_autosave(double now_s, double interval_s) {
    if (!m_project || m_autosaved) return {};
    if (m_changed_at == 0.0) m_changed_at = now_s;
    if (now_s - m_changed_at < interval_s) return {};
    Project copy = *m_project;
    copy.dir = autosave_dir(m_project->dir);
    copy.sections["focus"] = m_focus.to_json();
    std::array<std::shared_ptr<const Image>, 2> layers;
    for (int i = 0; i < 2; ++i)
        if (m_edits.layer(i).has_edits())
            layers[i] = std::make_shared<const Image>(m_edits.layer(i).edit());
    m_autosaved = true;
    // As write_work does, from the snapshot: the edit layers, then project.json's sections.
    return [copy, layers]() mutable {
        std::error_code ec;
        fs::create_directories(copy.dir, ec);
        ProjectEdits::save_layers(copy, layers[0].get(), layers[1].get());  // and "edits"
        copy.save_merged({"focus"});
    };
}

namespace {
bool same_edit(const AtlasEditor& a, const AtlasEditor& b) {
    if (a.has_edits() != b.has_edits()) return false;
    return !a.has_edits() || (a.width() == b.width() && a.height() == b.height() &&
                              a.edit().pixels == b.edit().pixels);
}
}  // namespace

bool StudioDoc::autosave_differs() const {
    const fs::path dir = autosave_dir(m_project->dir);
    const fs::path file = dir / Project::kFileName;
    if (!fs::exists(file)) return false;
    try {
        StudioDoc autosaved;
        autosaved.load_work(Project::from_json(read_json_file(file), m_project->dir, file.string()),
                            dir);
        return autosaved.m_focus.to_json() != m_focus.to_json() ||
               !same_edit(autosaved.m_edits.bg, m_edits.bg) ||
               !same_edit(autosaved.m_edits.fg, m_edits.fg);
    } catch (const std::exception&) {
        return true;  // offered all the same: restoring it names the problem, Discard removes it
    }
}

bool StudioDoc::commit(const std::string& label) {
    if (!m_project) return false;
    if (m_focus.to_json() == m_committed.to_json()) return false;
    m_undo.push_back({m_committed, label});
    if (m_undo.size() > kUndoLimit) m_undo.erase(m_undo.begin());
    m_redo.clear();  // a new change ends the branch that was undone
    m_committed = m_focus;
    return true;
}

void StudioDoc::step_history(std::vector<UndoEntry>& from, std::vector<UndoEntry>& to) {
    UndoEntry e = std::move(from.back());
    from.pop_back();
    to.push_back({m_focus, e.label});
    m_focus = std::move(e.track);
    m_committed = m_focus;
    mark_dirty();
}

bool StudioDoc::undo() {
    commit("Edit focus");  // a change still in progress becomes the entry undone
    if (m_undo.empty()) return false;
    step_history(m_undo, m_redo);
    return true;
}

bool StudioDoc::redo() {
    commit("Edit focus");  // a change in progress is a new branch: nothing is left to redo
    if (m_redo.empty()) return false;
    step_history(m_redo, m_undo);
    return true;
}

bool StudioDoc::has_newer_autosave() const {
    return m_newer_autosave;
}

void StudioDoc::restore_autosave() {
    if (!m_project) return;
    const fs::path dir = autosave_dir(m_project->dir);
    const fs::path file = dir / Project::kFileName;
    const json j = read_json_file(file);
    Project saved = Project::from_json(j, m_project->dir, file.string());
    load_work(saved, dir);
    m_newer_autosave = false;
    m_dirty = true;
    m_autosaved = true;
}

void StudioDoc::discard_autosave() {
    if (!m_project) return;
    std::error_code ec;
    fs::remove_all(autosave_dir(m_project->dir), ec);
    m_newer_autosave = false;
}

namespace {
fs::path recent_file() {
    const char* xdg = std::getenv("XDG_CONFIG_HOME");
    const char* home = std::getenv("HOME");
    fs::path base = xdg && *xdg ? fs::path(xdg) : fs::path(home ? home : "/tmp") / ".config";
    return base / "refocus" / "recent.json";
}
}  // namespace

std::vector<std::string> recent_projects() {
    try {
        const fs::path f = recent_file();
        if (!fs::exists(f)) return {};
        return json::parse(read_text_file(f.string())).get<std::vector<std::string>>();
    } catch (...) {
        return {};  // a damaged list is not worth an error: it is rebuilt on the next open
    }
}

void add_recent_project(const std::string& dir) {
    std::vector<std::string> list = recent_projects();
    const std::string abs = fs::absolute(dir).lexically_normal().string();
    list.erase(std::remove(list.begin(), list.end(), abs), list.end());
    list.insert(list.begin(), abs);
    if (list.size() > 10) list.resize(10);
    try {
        const fs::path f = recent_file();
        std::error_code ec;
        fs::create_directories(f.parent_path(), ec);
        write_file_atomic(f.string(), json(list).dump(2));
    } catch (...) {
        // A read-only home must not stop the studio.
    }
}

}  // namespace refocus
