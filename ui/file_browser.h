#pragma once
// The studio's file browser: an ImGui modal that picks a clip, a project, an image, a folder or
// a file name to save to, so that no path has to be typed. The listing (list_folder) is plain
// C++ with no ImGui, tested on its own (tests/test_file_browser.cpp). No LibTorch headers here:
// the file compiles in seconds and the Atlas panel's test links it alone.
//
//     FileBrowser b;  b.open({BrowseMode::Open, BrowseFilter::Media, "Open project", "Open"});
//     if (b.draw() == BrowseEvent::Picked) open_project(b.picked());   // every frame
#include <cstdint>
#include <string>
#include <vector>

namespace refocus {

// ---- the listing (no ImGui) ----

// What a browser lists besides folders. Media: clips and projects (File > Open); Clips: video
// files and image frames (New from clip); Images: frames only (atlas import and export);
// Folders: no files.
enum class BrowseFilter { Media, Clips, Images, Folders, All };

enum class EntryKind { Folder, Project, Video, Image, Other };

struct FolderEntry {
    std::string name;
    EntryKind kind = EntryKind::Other;
    uint64_t size = 0;     // bytes; 0 for folders
    int64_t modified = 0;  // seconds since 1970 (local time when shown)
    bool folder() const { return kind == EntryKind::Folder || kind == EntryKind::Project; }
};

struct FolderListing {
    std::string dir;  // absolute
    std::vector<FolderEntry> entries;
    int images = 0;        // image frames in it: the folder is an image sequence
    bool project = false;  // it holds project.json
    std::string error;     // why the folder could not be read, naming it; entries are then empty
};

// Folders (projects among them) first, then the files the filter keeps, each group sorted by
// name without regard to case. Names starting with '.' are left out unless `show_hidden`.
FolderListing list_folder(const std::string& dir, BrowseFilter filter, bool show_hidden);
// By the name alone for files; a folder holding project.json is a project.
EntryKind entry_kind(const std::string& path);
bool filter_keeps(BrowseFilter filter, EntryKind kind);
// A picked image frame stands for its folder's image sequence when a clip is wanted.
std::string clip_for_pick(const std::string& path, BrowseFilter filter);
std::string format_size(uint64_t bytes);   // "812 B", "1.4 MB"
std::string format_date(int64_t seconds);  // "2024-05-01 14:02", local time

// ---- places shared by every browser of this process ----

// The left column: folders picked before in this session, the open project's folder, recent
// projects. The studio keeps `project` and `recent` up to date; picks add to `picked`.
struct BrowserPlaces {
    std::string project;
    std::vector<std::string> recent, picked;
};
BrowserPlaces& browser_places();

// The start screen (viewer_panel.cpp) draws outside the studio's dialogs: its buttons leave a
// request here, and the studio takes it in its next frame and runs it as the File menu would.
struct StartRequest {
    enum Kind { None, Open, NewFromClip, OpenPath } kind = None;
    std::string path;  // OpenPath: a recent project
};
void post_start_request(const StartRequest& r);
StartRequest take_start_request();

// A tooltip on the last item, also while it is disabled (ImGui 1.86 has no SetItemTooltip).
void item_tooltip(const char* text);

// ---- the dialog ----

// Open: a file or a project (folders are entered); Folder: a folder, existing or new (the "new
// folder name" field); Save: a file name in a folder (the file is not written here).
enum class BrowseMode { Open, Folder, Save };

struct BrowseOptions {
    BrowseMode mode = BrowseMode::Open;
    BrowseFilter filter = BrowseFilter::Media;
    std::string title = "Open";  // the dialog's title, also its ImGui id
    std::string ok = "Open";     // the pick button's label
    std::string dir;   // where it opens; empty: the last folder picked, the project's, the working
    std::string name;  // Folder: the proposed new folder; Save: the proposed file name
};

enum class BrowseEvent { None, Picked, Cancelled };

class FileBrowser {
  public:
    void open(const BrowseOptions& opts);  // shows from the next draw()
    void close();                          // without an event (scripts)
    bool is_open() const { return m_open; }
    // Draws the modal while it is open (call every frame, outside other popups); Picked once
    // when a path was picked (then picked() holds it, absolute), Cancelled once on Cancel.
    BrowseEvent draw();
    const std::string& picked() const { return m_picked; }
    const std::string& dir() const { return m_list.dir; }
    const FolderListing& listing() const { return m_list; }
    // Scripts: what a click (select) or a double-click (activate) on `name` in the current
    // folder does. False when it is not listed.
    bool select(const std::string& name);
    bool activate(const std::string& name);
    // Scripts: Open: activate(name); Folder and Save: `name` typed into the name field, then
    // the pick button. False when refused (problem() says why) or not listed.
    bool accept(const std::string& name);
    const std::string& problem() const { return m_problem; }
    void navigate(const std::string& dir);

  private:
    void activate(size_t index);
    int index_of(const std::string& name) const;  // -1: not listed
    void pick(const std::string& path);
    void pick_with_ok();
    void draw_top_bar();
    void draw_places(float height);
    void draw_list(float height);
    void draw_footer();
    std::string target() const;  // what the pick button picks now; empty: nothing yet
    std::string row_tip(const FolderEntry& e) const;

    BrowseOptions m_opt;
    bool m_open = false, m_want_open = false, m_closing = false;
    bool m_show_hidden = false, m_all_files = false;
    FolderListing m_list;
    int m_selected = -1;
    int m_hover_row = -1;  // the row under the pointer, since when (its tooltip waits)
    double m_hover_since = 0.0;
    std::string m_picked, m_problem;  // m_problem: why the last pick was refused
    BrowseEvent m_event = BrowseEvent::None;
    char m_path_buf[1024] = {0};
    char m_name_buf[256] = {0};
};

}  // namespace refocus
