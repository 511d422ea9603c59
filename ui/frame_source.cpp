#include "frame_source.h"

#include <algorithm>

namespace refocus {

FrameSource::FrameSource(const std::string& path) {
    if (is_project_path(path)) {
        m_project = std::make_unique<Project>(Project::load(path));
        m_width = m_project->width;
        m_height = m_project->height;
        m_frames = m_project->frames;
        m_fps = m_project->fps;
        m_label = m_project->name + " (project)";
    } else {
        m_clip = ClipReader::open(path);
        m_width = m_clip->info().width;
        m_height = m_clip->info().height;
        m_frames = m_clip->info().frames;
        m_fps = m_clip->info().fps;
        m_label = path;
    }
}

Image FrameSource::linear(int index) {
    index = std::clamp(index, 0, m_frames - 1);
    return m_project ? m_project->read_frame(index) : m_clip->read(index);
}

}  // namespace refocus
