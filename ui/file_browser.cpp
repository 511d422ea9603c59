#include "file_browser.h"

#include <imgui.h>
#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <system_error>

namespace refocus {

namespace fs = std::filesystem;

namespace {

std::string lower(std::string s) {
    std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
    return s;
}

// The formats Refocus reads (engine/io/clip.cpp): videos through FFmpeg, frames through OIIO.
bool is_video_ext(const std::string& e) {
    static const char* exts[] = {".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v"};
    return std::any_of(std::begin(exts), std::end(exts), [&](const char* x) { return e == x; });
}
bool is_image_ext(const std::string& e) {
    static const char* exts[] = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr"};
    return std::any_of(std::begin(exts), std::end(exts), [&](const char* x) { return e == x; });
}

// "/a/b/" and "/a/./b" both as "/a/b", so that places compare equal to the folder shown.
std::string clean_dir(const std::string& dir) {
    std::error_code ec;
    fs::path p = fs::absolute(dir.empty() ? fs::path(".") : fs::path(dir), ec).lexically_normal();
    if (!p.has_filename() && p.has_parent_path() && p != p.root_path()) p = p.parent_path();
    return p.string();
}

std::string home_dir() {
    const char* h = std::getenv("HOME");  // where the user keeps files, as a desktop dialog has
    return h && *h ? h : "/";
}

std::string expand_home(const std::string& p) {
    if (p == "~" || p.rfind("~/", 0) == 0) return home_dir() + p.substr(1);
    return p;
}

bool less_name(const FolderEntry& a, const FolderEntry& b) {
    if (a.folder() != b.folder()) return a.folder();
    const std::string la = lower(a.name), lb = lower(b.name);
    return la != lb ? la < lb : a.name < b.name;
}

const char* kind_label(EntryKind k) {
    switch (k) {
        case EntryKind::Folder:
            return "folder";
        case EntryKind::Project:
            return "project";
        case EntryKind::Video:
            return "video";
        case EntryKind::Image:
            return "image";
        default:
            return "";
    }
}

ImVec4 kind_colour(EntryKind k) {
    switch (k) {
        case EntryKind::Folder:
            return ImVec4(0.95f, 0.85f, 0.55f, 1.0f);
        case EntryKind::Project:
            return ImVec4(0.55f, 0.80f, 1.0f, 1.0f);
        case EntryKind::Other:
            return ImGui::GetStyleColorVec4(ImGuiCol_TextDisabled);
        default:
            return ImGui::GetStyleColorVec4(ImGuiCol_Text);
    }
}

const ImVec4 kErrorColour(1.0f, 0.45f, 0.4f, 1.0f);

}  // namespace

// ---- the listing ----

namespace {
EntryKind kind_by_name(const std::string& name) {
    const std::string e = lower(fs::path(name).extension().string());
    if (is_video_ext(e)) return EntryKind::Video;
    if (is_image_ext(e)) return EntryKind::Image;
    return EntryKind::Other;
}
}  // namespace

EntryKind entry_kind(const std::string& path) {
    std::error_code ec;
    if (fs::is_directory(path, ec))
        return fs::exists(fs::path(path) / "project.json", ec) ? EntryKind::Project
                                                               : EntryKind::Folder;
    return kind_by_name(fs::path(path).filename().string());
}

bool filter_keeps(BrowseFilter filter, EntryKind kind) {
    if (kind == EntryKind::Folder || kind == EntryKind::Project) return true;
    switch (filter) {
        case BrowseFilter::Media:
        case BrowseFilter::Clips:
            return kind == EntryKind::Video || kind == EntryKind::Image;
        case BrowseFilter::Images:
            return kind == EntryKind::Image;
        case BrowseFilter::Folders:
            return false;
        case BrowseFilter::All:
            return true;
    }
    return true;
}

FolderListing list_folder(const std::string& dir, BrowseFilter filter, bool show_hidden) {
    FolderListing out;
    out.dir = clean_dir(dir);
    std::error_code ec;
    if (!fs::is_directory(out.dir, ec)) {
        out.error = out.dir + ": " + (fs::exists(out.dir, ec) ? "not a folder" : "no such folder");
        return out;
    }
    out.project = fs::exists(fs::path(out.dir) / "project.json", ec);
    fs::directory_iterator it(out.dir, ec);
    for (; !ec && it != fs::directory_iterator(); it.increment(ec)) {
        const fs::path& p = it->path();
        FolderEntry e;
        e.name = p.filename().string();
        if (!show_hidden && e.name[0] == '.') continue;
        // One stat an entry (a sequence's folder holds thousands): type, size, exact mtime
        // (C++17 has no file_clock to time_t). A broken link is a file by its name.
        struct stat st;
        const bool ok = ::stat(p.c_str(), &st) == 0;
        std::error_code pec;
        if (ok && S_ISDIR(st.st_mode))
            e.kind = fs::exists(p / "project.json", pec) ? EntryKind::Project : EntryKind::Folder;
        else
            e.kind = kind_by_name(e.name);
        if (e.kind == EntryKind::Image) ++out.images;
        if (!filter_keeps(filter, e.kind)) continue;
        if (ok) {
            e.size = e.folder() ? 0 : static_cast<uint64_t>(st.st_size);
            e.modified = static_cast<int64_t>(st.st_mtime);
        }
        out.entries.push_back(std::move(e));
    }
    if (ec) {
        out.error = out.dir + ": cannot read the folder: " + ec.message();
        out.entries.clear();
        out.images = 0;
    }
    std::sort(out.entries.begin(), out.entries.end(), less_name);
    return out;
}

std::string clip_for_pick(const std::string& path, BrowseFilter filter) {
    if ((filter == BrowseFilter::Media || filter == BrowseFilter::Clips) &&
        entry_kind(path) == EntryKind::Image)
        return fs::path(path).parent_path().string();
    return path;
}

std::string format_size(uint64_t bytes) {
    const char* units[] = {"B", "KB", "MB", "GB", "TB"};
    double v = static_cast<double>(bytes);
    int u = 0;
    while (v >= 1024.0 && u < 4) v /= 1024.0, ++u;
    char b[32];
    std::snprintf(b, sizeof b, u == 0 ? "%.0f %s" : "%.1f %s", v, units[u]);
    return b;
}

std::string format_date(int64_t seconds) {
    const std::time_t t = static_cast<std::time_t>(seconds);
    std::tm tm{};
    if (!localtime_r(&t, &tm)) return "";
    char b[32];
    std::strftime(b, sizeof b, "%Y-%m-%d %H:%M", &tm);
    return b;
}

// ---- places and requests ----

BrowserPlaces& browser_places() {
    static BrowserPlaces places;
    return places;
}

namespace {
StartRequest g_start_request;
}

void post_start_request(const StartRequest& r) {
    g_start_request = r;
}

StartRequest take_start_request() {
    StartRequest r = g_start_request;
    g_start_request = {};
    return r;
}

void item_tooltip(const char* text) {
    if (ImGui::IsItemHovered(ImGuiHoveredFlags_AllowWhenDisabled)) ImGui::SetTooltip("%s", text);
}

// ---- the dialog ----

void FileBrowser::open(const BrowseOptions& opts) {
    m_opt = opts;
    m_open = m_want_open = true;
    m_closing = false;
    m_event = BrowseEvent::None;
    m_all_files = false;
    m_problem.clear();
    std::snprintf(m_name_buf, sizeof m_name_buf, "%s", opts.name.c_str());
    const BrowserPlaces& pl = browser_places();
    std::string start = expand_home(opts.dir);
    if (start.empty()) start = !pl.picked.empty() ? pl.picked.front() : pl.project;
    // A folder still to be made (a new project's): open on the nearest one that exists.
    std::error_code ec;
    fs::path p = clean_dir(start);
    while (!fs::is_directory(p, ec) && p.has_parent_path() && p != p.root_path())
        p = p.parent_path();
    navigate(p.string());
}

void FileBrowser::close() {
    m_closing = m_open;  // the popup is closed from inside it, in the next draw()
}

void FileBrowser::navigate(const std::string& dir) {
    const BrowseFilter f = m_all_files                        ? BrowseFilter::All
                           : m_opt.mode == BrowseMode::Folder ? BrowseFilter::Folders
                                                              : m_opt.filter;
    m_list = list_folder(expand_home(dir), f, m_show_hidden);
    m_selected = -1;
    m_problem.clear();
    std::snprintf(m_path_buf, sizeof m_path_buf, "%s", m_list.dir.c_str());
}

int FileBrowser::index_of(const std::string& name) const {
    for (size_t i = 0; i < m_list.entries.size(); ++i)
        if (m_list.entries[i].name == name) return static_cast<int>(i);
    return -1;
}

bool FileBrowser::select(const std::string& name) {
    const int i = index_of(name);
    if (i >= 0) m_selected = i;
    return i >= 0;
}

bool FileBrowser::activate(const std::string& name) {
    const int i = index_of(name);
    if (i >= 0) activate(static_cast<size_t>(i));
    return i >= 0;
}

bool FileBrowser::accept(const std::string& name) {
    if (m_opt.mode == BrowseMode::Open) return activate(name);
    std::snprintf(m_name_buf, sizeof m_name_buf, "%s", name.c_str());
    pick_with_ok();
    return m_problem.empty();
}

// A double-click: enters a folder, picks a project (where projects are wanted) or a file.
void FileBrowser::activate(size_t index) {
    const FolderEntry e = m_list.entries[index];
    const std::string path = (fs::path(m_list.dir) / e.name).string();
    const bool wants_project =
        m_opt.mode == BrowseMode::Open && m_opt.filter == BrowseFilter::Media;
    if (e.kind == EntryKind::Folder || (e.kind == EntryKind::Project && !wants_project)) {
        navigate(path);
    } else if (e.kind == EntryKind::Project || m_opt.mode == BrowseMode::Open) {
        pick(clip_for_pick(path, m_opt.filter));
    } else if (m_opt.mode == BrowseMode::Save) {
        std::snprintf(m_name_buf, sizeof m_name_buf, "%s", e.name.c_str());
        pick_with_ok();
    }
}

std::string FileBrowser::target() const {
    const fs::path dir(m_list.dir);
    const bool have_sel = m_selected >= 0 && m_selected < int(m_list.entries.size());
    switch (m_opt.mode) {
        case BrowseMode::Open:
            if (!have_sel) return "";
            if (m_list.entries[m_selected].kind == EntryKind::Folder) return "";
            if (m_list.entries[m_selected].kind == EntryKind::Project &&
                m_opt.filter != BrowseFilter::Media)
                return "";
            return clip_for_pick((dir / m_list.entries[m_selected].name).string(), m_opt.filter);
        case BrowseMode::Folder:
            if (m_name_buf[0]) return (dir / m_name_buf).lexically_normal().string();
            if (have_sel) return (dir / m_list.entries[m_selected].name).string();
            return m_list.dir;
        case BrowseMode::Save:
            return m_name_buf[0] ? (dir / m_name_buf).lexically_normal().string() : "";
    }
    return "";
}

void FileBrowser::pick_with_ok() {
    if (!m_list.error.empty()) return;
    if (m_opt.mode == BrowseMode::Open) {
        if (m_selected >= 0 && m_selected < int(m_list.entries.size())) activate(m_selected);
        return;
    }
    const std::string t = target();
    std::error_code ec;
    if (t.empty()) {
        m_problem = "give the file a name";
    } else if (m_opt.mode == BrowseMode::Folder && fs::exists(t, ec) && !fs::is_directory(t, ec)) {
        m_problem = t + ": exists and is not a folder";
    } else if (m_opt.mode == BrowseMode::Save && fs::is_directory(t, ec)) {
        m_problem = t + ": is a folder; give a file name";
    } else {
        pick(t);
    }
}

void FileBrowser::pick(const std::string& path) {
    m_picked = clean_dir(path);
    m_event = BrowseEvent::Picked;
    m_open = false;
    // Remember the folder the pick is in (or the picked folder itself) for the next dialogs.
    std::error_code ec;
    fs::path place = m_picked;
    if (m_opt.mode != BrowseMode::Folder || !fs::is_directory(place, ec))
        place = place.parent_path();
    auto& picked = browser_places().picked;
    picked.erase(std::remove(picked.begin(), picked.end(), place.string()), picked.end());
    picked.insert(picked.begin(), place.string());
    if (picked.size() > 8) picked.resize(8);
}

void FileBrowser::draw_top_bar() {
    if (ImGui::Button("Up") || (ImGui::IsKeyPressed(ImGui::GetKeyIndex(ImGuiKey_Backspace)) &&
                                !ImGui::GetIO().WantTextInput))
        navigate(fs::path(m_list.dir).parent_path().string());
    item_tooltip("The folder above this one (Backspace)");
    ImGui::SameLine();
    ImGui::SetNextItemWidth(-260);
    if (ImGui::InputText("##path", m_path_buf, sizeof m_path_buf,
                         ImGuiInputTextFlags_EnterReturnsTrue)) {
        const std::string typed = expand_home(m_path_buf);
        std::error_code ec;
        if (fs::is_directory(typed, ec)) {
            navigate(typed);
        } else if (fs::is_directory(fs::absolute(typed, ec).parent_path(), ec)) {
            // A file's path: go to its folder and do what a double-click on it does.
            const fs::path p = fs::absolute(typed, ec);
            navigate(p.parent_path().string());
            if (!activate(p.filename().string())) {
                if (m_opt.mode == BrowseMode::Open)
                    m_problem = p.string() + ": no such file here";
                else
                    std::snprintf(m_name_buf, sizeof m_name_buf, "%s",
                                  p.filename().string().c_str());
            }
        } else {
            m_problem = typed + ": no such folder";
        }
    }
    item_tooltip("The folder shown. Type a folder or a file and press Enter to go there");
    ImGui::SameLine();
    if (ImGui::Button("Refresh")) navigate(m_list.dir);
    item_tooltip("List the folder again (files written since it was opened)");
    ImGui::SameLine();
    if (ImGui::Checkbox("hidden files", &m_show_hidden)) navigate(m_list.dir);
    item_tooltip("Show files and folders whose names start with a dot");
}

void FileBrowser::draw_places(float height) {
    ImGui::BeginChild("places", ImVec2(210, height), true);
    const BrowserPlaces& pl = browser_places();
    std::string go, go_select;
    auto place = [&](const std::string& label, const std::string& path, bool project = false) {
        const std::string target = project ? fs::path(path).parent_path().string() : path;
        ImGui::PushID(path.c_str());
        if (ImGui::Selectable(label.c_str(), !project && m_list.dir == path)) {
            go = target;
            if (project) go_select = fs::path(path).filename().string();
        }
        item_tooltip(path.c_str());
        ImGui::PopID();
    };
    std::error_code ec;
    place("Home", clean_dir(home_dir()));
    place("Working folder", clean_dir(fs::current_path(ec).string()));
    if (!pl.project.empty()) place("Open project's folder", clean_dir(pl.project));
    if (!pl.picked.empty()) {
        ImGui::Separator();
        ImGui::TextDisabled("Picked before");
        for (const std::string& p : pl.picked) place(fs::path(p).filename().string(), p);
    }
    if (!pl.recent.empty()) {
        ImGui::Separator();
        ImGui::TextDisabled("Recent projects");
        for (const std::string& p : pl.recent)
            place(fs::path(clean_dir(p)).filename().string(), clean_dir(p), true);
    }
    ImGui::EndChild();
    if (go.empty()) return;
    navigate(go);
    select(go_select);
}

std::string FileBrowser::row_tip(const FolderEntry& e) const {
    const bool wants_project =
        m_opt.mode == BrowseMode::Open && m_opt.filter == BrowseFilter::Media;
    const bool clips = m_opt.filter == BrowseFilter::Media || m_opt.filter == BrowseFilter::Clips;
    switch (e.kind) {
        case EntryKind::Folder:
            return "Double-click: go into the folder";
        case EntryKind::Project:
            return wants_project ? "A Refocus project: double-click opens it"
                                 : "A Refocus project's folder: double-click goes into it";
        case EntryKind::Image:
            if (m_opt.mode == BrowseMode::Open && clips)
                return "A frame: double-click picks its folder's image sequence";
            break;
        case EntryKind::Video:
            if (m_opt.mode == BrowseMode::Open && m_opt.filter == BrowseFilter::Media)
                return "A video: double-click opens it (a project is made beside it)";
            break;
        default:
            break;
    }
    return m_opt.mode == BrowseMode::Save ? "Double-click: write over this file"
                                          : "Double-click: pick this file";
}

void FileBrowser::draw_list(float height) {
    int activated = -1;
    const ImGuiTableFlags flags = ImGuiTableFlags_ScrollY | ImGuiTableFlags_RowBg |
                                  ImGuiTableFlags_BordersOuter | ImGuiTableFlags_BordersInnerV |
                                  ImGuiTableFlags_Resizable;
    if (!ImGui::BeginTable("entries", 4, flags, ImVec2(0, height))) return;
    ImGui::TableSetupScrollFreeze(0, 1);
    ImGui::TableSetupColumn("Name", ImGuiTableColumnFlags_WidthStretch);
    ImGui::TableSetupColumn("Kind", ImGuiTableColumnFlags_WidthFixed, 60);
    ImGui::TableSetupColumn("Size", ImGuiTableColumnFlags_WidthFixed, 70);
    ImGui::TableSetupColumn("Modified", ImGuiTableColumnFlags_WidthFixed, 120);
    ImGui::TableHeadersRow();
    // Only the rows in view are drawn: a sequence's folder lists thousands of frames.
    ImGuiListClipper clipper;
    clipper.Begin(static_cast<int>(m_list.entries.size()));
    int hovered = -1;
    while (clipper.Step())
        for (int i = clipper.DisplayStart; i < clipper.DisplayEnd; ++i) {
            const FolderEntry& e = m_list.entries[i];
            ImGui::TableNextRow();
            ImGui::TableNextColumn();
            ImGui::PushID(i);
            ImGui::PushStyleColor(ImGuiCol_Text, kind_colour(e.kind));
            const std::string label = e.folder() ? e.name + "/" : e.name;
            if (ImGui::Selectable(
                    label.c_str(), m_selected == i,
                    ImGuiSelectableFlags_SpanAllColumns | ImGuiSelectableFlags_AllowDoubleClick)) {
                m_selected = i;
                m_problem.clear();
                if (m_opt.mode == BrowseMode::Save && !e.folder())
                    std::snprintf(m_name_buf, sizeof m_name_buf, "%s", e.name.c_str());
                if (ImGui::IsMouseDoubleClicked(0)) activated = i;
            }
            ImGui::PopStyleColor();
            if (ImGui::IsItemHovered()) hovered = i;
            ImGui::TableNextColumn();
            ImGui::TextDisabled("%s", kind_label(e.kind));
            ImGui::TableNextColumn();
            if (!e.folder()) ImGui::TextUnformatted(format_size(e.size).c_str());
            ImGui::TableNextColumn();
            ImGui::TextDisabled("%s", format_date(e.modified).c_str());
            ImGui::PopID();
        }
    // What a double-click on the row does, once the pointer rests on it (not while it sweeps).
    const double now = ImGui::GetTime();
    if (hovered != m_hover_row) m_hover_row = hovered, m_hover_since = now;
    if (hovered >= 0 && now - m_hover_since > 0.6)
        ImGui::SetTooltip("%s", row_tip(m_list.entries[hovered]).c_str());
    if (m_list.entries.empty() && m_list.error.empty()) {
        ImGui::TableNextRow();
        ImGui::TableNextColumn();
        ImGui::TextDisabled(m_all_files || m_opt.filter == BrowseFilter::All
                                ? "(empty folder)"
                                : "(nothing of the kind asked for here)");
    }
    ImGui::EndTable();
    if (activated >= 0) activate(static_cast<size_t>(activated));  // may list another folder
}

void FileBrowser::draw_footer() {
    const bool clips = m_opt.filter == BrowseFilter::Media || m_opt.filter == BrowseFilter::Clips;
    if (m_opt.mode == BrowseMode::Open) {
        if (ImGui::Checkbox("all files", &m_all_files)) navigate(m_list.dir);
        item_tooltip(clips ? "Also list files Refocus does not read as clips"
                           : "Also list files of other kinds");
        if (clips && m_list.images > 0) {
            ImGui::SameLine();
            const std::string l = "Use this folder's " + std::to_string(m_list.images) + " frames";
            if (ImGui::Button(l.c_str())) pick(m_list.dir);
            item_tooltip("The folder's images are the frames of one clip, in name order");
        }
        if (m_opt.filter == BrowseFilter::Media && m_list.project) {
            ImGui::SameLine();
            if (ImGui::Button("Open this project")) pick(m_list.dir);
            item_tooltip("This folder holds project.json: open it");
        }
    } else {
        ImGui::SetNextItemWidth(360);
        const bool folder = m_opt.mode == BrowseMode::Folder;
        if (ImGui::InputText(folder ? "new folder name" : "file name", m_name_buf,
                             sizeof m_name_buf, ImGuiInputTextFlags_EnterReturnsTrue))
            pick_with_ok();
        item_tooltip(folder ? "A folder to make inside the one shown (made when it is used);\n"
                              "empty: the folder shown, or the folder selected"
                            : "The file to write, inside the folder shown");
    }
    const std::string t = target();
    std::error_code ec;
    if (!m_list.error.empty() || !m_problem.empty()) {
        ImGui::TextColored(kErrorColour, "%s",
                           (!m_problem.empty() ? m_problem : m_list.error).c_str());
    } else if (t.empty()) {
        ImGui::TextDisabled(m_opt.mode == BrowseMode::Save ? "Type a file name"
                            : clips ? "Double-click a clip or a project, or enter a folder"
                                    : "Double-click a file, or enter a folder");
    } else {
        const bool replaces = m_opt.mode == BrowseMode::Save && fs::exists(t, ec);
        ImGui::TextDisabled("%s%s", replaces ? "replaces " : "", t.c_str());
    }
    const ImGuiStyle& style = ImGui::GetStyle();
    const float w = ImGui::CalcTextSize(m_opt.ok.c_str()).x + ImGui::CalcTextSize("Cancel").x +
                    4 * style.FramePadding.x + style.ItemSpacing.x;
    ImGui::SetCursorPosX(ImGui::GetWindowContentRegionMax().x - w);
    ImGui::BeginDisabled(t.empty() && m_opt.mode != BrowseMode::Save);
    if (ImGui::Button(m_opt.ok.c_str())) pick_with_ok();
    ImGui::EndDisabled();
    item_tooltip(t.empty() ? "Select something first" : t.c_str());
    ImGui::SameLine();
    if (ImGui::Button("Cancel") || (ImGui::IsKeyPressed(ImGui::GetKeyIndex(ImGuiKey_Escape)) &&
                                    !ImGui::GetIO().WantTextInput)) {
        m_open = false;
        m_event = BrowseEvent::Cancelled;
    }
    item_tooltip("Close without picking (Escape)");
}

BrowseEvent FileBrowser::draw() {
    const char* id = m_opt.title.c_str();
    if (m_want_open) {
        ImGui::OpenPopup(id);
        m_want_open = false;
    }
    if (m_open) {
        const ImGuiViewport* vp = ImGui::GetMainViewport();
        ImGui::SetNextWindowPos(vp->GetCenter(), ImGuiCond_Appearing, ImVec2(0.5f, 0.5f));
        ImGui::SetNextWindowSize(
            ImVec2(std::min(940.0f, vp->WorkSize.x - 40), std::min(580.0f, vp->WorkSize.y - 40)),
            ImGuiCond_Appearing);
        bool keep = true;
        // Opaque: a list of names reads badly over the viewer's image.
        ImVec4 bg = ImGui::GetStyleColorVec4(ImGuiCol_PopupBg);
        bg.w = 1.0f;
        ImGui::PushStyleColor(ImGuiCol_PopupBg, bg);
        const bool shown = ImGui::BeginPopupModal(id, &keep, ImGuiWindowFlags_NoSavedSettings);
        ImGui::PopStyleColor();
        if (shown) {
            if (m_closing) {
                m_open = m_closing = false;
            } else {
                draw_top_bar();
                const float footer =
                    2 * ImGui::GetFrameHeightWithSpacing() + ImGui::GetTextLineHeightWithSpacing();
                const float h = std::max(80.0f, ImGui::GetContentRegionAvail().y - footer);
                draw_places(h);
                ImGui::SameLine();
                draw_list(h);
                draw_footer();
            }
            if (!m_open) ImGui::CloseCurrentPopup();  // picked or cancelled in this frame
            ImGui::EndPopup();
        } else {
            // Closed from its title bar, or by a modal opened over the whole window (an error).
            if (!keep) m_event = BrowseEvent::Cancelled;
            m_open = m_closing = false;
        }
    }
    const BrowseEvent e = m_event;
    m_event = BrowseEvent::None;
    return e;
}

}  // namespace refocus
