#pragma once
// One writer per project: an advisory flock(2) on <project>/.lock, whose text names the holder
// ("pid 1234: refocus fit"). The kernel drops the lock when its process dies, so a stale file
// (dead holder) is simply taken over. Re-entrant within a process (the studio's threads).
#include <memory>
#include <string>

#include "util/fs.h"

namespace refocus {

class ProjectLock {
  public:
    // Takes the lock on `project_dir` for `what` ("refocus fit"); throws refocus::Error naming
    // the holder when another process has it.
    static std::unique_ptr<ProjectLock> acquire(const fs::path& project_dir,
                                                const std::string& what);
    static fs::path file_of(const fs::path& project_dir) { return project_dir / ".lock"; }
    // The holder's line ("pid 1234: refocus fit"), or "" when nobody holds it.
    static std::string holder(const fs::path& project_dir);
    ~ProjectLock();
    ProjectLock(const ProjectLock&) = delete;
    ProjectLock& operator=(const ProjectLock&) = delete;

  private:
    explicit ProjectLock(std::string key) : m_key(std::move(key)) {}
    std::string m_key;
};

}  // namespace refocus
