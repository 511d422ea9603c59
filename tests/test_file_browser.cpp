// The file browser's non-GUI part (ui/file_browser.h) on a scratch folder: what is listed for
// each filter, in which order, hidden names, sizes, errors naming the folder, and what a
// double-click picks. Built from ui/file_browser.cpp alone: no window, no torch.
#define DOCTEST_CONFIG_IMPLEMENT_WITH_MAIN
#include <doctest/doctest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "file_browser.h"

using namespace refocus;
namespace fs = std::filesystem;

namespace {

void touch(const fs::path& p, size_t bytes = 0) {
    std::ofstream f(p, std::ios::binary);
    f << std::string(bytes, 'x');
}

// A folder with clips, frames, a project, other files and hidden names.
fs::path make_folder(const std::string& name) {
    const fs::path dir = fs::path(FILE_BROWSER_TMP) / name;
    fs::remove_all(dir);
    fs::create_directories(dir / "Zeta");
    fs::create_directories(dir / "alpha");
    fs::create_directories(dir / ".cache");
    fs::create_directories(dir / "shot_refocus");
    touch(dir / "shot_refocus" / "project.json", 2);
    touch(dir / "b.MP4", 1536);
    touch(dir / "a.mov", 812);
    touch(dir / "frame_0001.png", 10);
    touch(dir / "C.exr", 10);
    touch(dir / "notes.txt", 3);
    touch(dir / ".hidden.mp4", 1);
    return dir;
}

std::vector<std::string> names(const FolderListing& l) {
    std::vector<std::string> out;
    for (const FolderEntry& e : l.entries) out.push_back(e.name);
    return out;
}

using Names = std::vector<std::string>;

}  // namespace

TEST_CASE("list_folder: folders first, then what the filter keeps, sorted without case") {
    const fs::path dir = make_folder("listing");
    const FolderListing media = list_folder(dir.string(), BrowseFilter::Media, false);
    CHECK(media.error.empty());
    CHECK(media.dir == fs::absolute(dir).lexically_normal().string());
    CHECK(names(media) ==
          Names{"alpha", "shot_refocus", "Zeta", "a.mov", "b.MP4", "C.exr", "frame_0001.png"});
    CHECK(media.entries[1].kind == EntryKind::Project);
    CHECK(media.entries[0].kind == EntryKind::Folder);
    CHECK(media.entries[3].kind == EntryKind::Video);
    CHECK(media.entries[4].kind == EntryKind::Video);  // upper-case extension
    CHECK(media.entries[5].kind == EntryKind::Image);
    CHECK(media.images == 2);
    CHECK_FALSE(media.project);
    CHECK(media.entries[3].size == 812);
    CHECK(media.entries[4].size == 1536);
    CHECK(media.entries[3].modified > 0);

    CHECK(names(list_folder(dir.string(), BrowseFilter::Images, false)) ==
          Names{"alpha", "shot_refocus", "Zeta", "C.exr", "frame_0001.png"});
    CHECK(names(list_folder(dir.string(), BrowseFilter::Folders, false)) ==
          Names{"alpha", "shot_refocus", "Zeta"});
    const Names all = names(list_folder(dir.string(), BrowseFilter::All, false));
    CHECK(std::find(all.begin(), all.end(), "notes.txt") != all.end());
    CHECK(std::find(all.begin(), all.end(), ".hidden.mp4") == all.end());
    const Names hidden = names(list_folder(dir.string(), BrowseFilter::Media, true));
    CHECK(hidden.front() == ".cache");
    CHECK(std::find(hidden.begin(), hidden.end(), ".hidden.mp4") != hidden.end());
    CHECK(list_folder((dir / "shot_refocus").string(), BrowseFilter::Media, false).project);
    // A trailing slash or a "." lists the same folder under the same name.
    CHECK(list_folder(dir.string() + "/./", BrowseFilter::Media, false).dir == media.dir);
}

TEST_CASE("list_folder: a folder that cannot be read is an error naming it") {
    const fs::path dir = make_folder("errors");
    const FolderListing missing = list_folder((dir / "nope").string(), BrowseFilter::All, false);
    CHECK(missing.entries.empty());
    CHECK(missing.error.find((dir / "nope").string()) != std::string::npos);
    CHECK(missing.error.find("no such folder") != std::string::npos);
    const FolderListing file = list_folder((dir / "a.mov").string(), BrowseFilter::All, false);
    CHECK(file.error.find("not a folder") != std::string::npos);
    if (geteuid() != 0) {  // root reads every folder
        fs::create_directories(dir / "locked");
        touch(dir / "locked" / "x.mp4");
        fs::permissions(dir / "locked", fs::perms::none);
        const FolderListing locked =
            list_folder((dir / "locked").string(), BrowseFilter::All, false);
        fs::permissions(dir / "locked", fs::perms::owner_all);
        CHECK(locked.entries.empty());
        CHECK(locked.error.find((dir / "locked").string()) != std::string::npos);
    }
}

TEST_CASE("what a pick stands for, sizes and dates as shown") {
    const fs::path dir = make_folder("picks");
    const std::string frame = (dir / "frame_0001.png").string();
    CHECK(clip_for_pick(frame, BrowseFilter::Clips) == dir.string());  // the image sequence
    CHECK(clip_for_pick(frame, BrowseFilter::Images) == frame);        // an atlas image
    CHECK(clip_for_pick((dir / "a.mov").string(), BrowseFilter::Media) == (dir / "a.mov").string());
    CHECK(entry_kind((dir / "shot_refocus").string()) == EntryKind::Project);
    CHECK(entry_kind((dir / "notes.txt").string()) == EntryKind::Other);
    CHECK(format_size(812) == "812 B");
    CHECK(format_size(1536) == "1.5 KB");
    CHECK(format_size(3u * 1024 * 1024 * 1024) == "3.0 GB");
    CHECK(format_date(0).size() == 16);  // "YYYY-MM-DD hh:mm"
}

TEST_CASE("FileBrowser: double-clicks enter folders and pick projects and clips") {
    const fs::path dir = make_folder("dialog");
    const std::string abs = fs::absolute(dir).lexically_normal().string();
    FileBrowser b;
    BrowseOptions o;
    o.dir = (dir / "not_made_yet" / "deeper").string();  // opens on the nearest folder there is
    b.open(o);
    CHECK(b.is_open());
    CHECK(b.dir() == abs);
    CHECK(b.activate("alpha"));  // a folder: entered
    CHECK(b.is_open());
    CHECK(b.dir() == abs + "/alpha");
    b.navigate(dir.string());
    CHECK_FALSE(b.activate("missing.mp4"));
    CHECK(b.activate("shot_refocus"));  // a project: picked
    CHECK_FALSE(b.is_open());
    CHECK(b.picked() == abs + "/shot_refocus");
    CHECK(browser_places().picked.front() == abs);

    o.filter = BrowseFilter::Clips;  // New from clip: a project is a folder, a frame its sequence
    b.open(o);
    CHECK(b.dir() == abs);  // the folder picked before
    CHECK(b.activate("shot_refocus"));
    CHECK(b.is_open());
    b.navigate(dir.string());
    CHECK(b.activate("frame_0001.png"));
    CHECK(b.picked() == abs);

    o = BrowseOptions{};
    o.mode = BrowseMode::Save;
    o.filter = BrowseFilter::Images;
    o.dir = dir.string();
    b.open(o);
    CHECK(b.activate("C.exr"));  // an existing file to write over
    CHECK(b.picked() == abs + "/C.exr");
}
