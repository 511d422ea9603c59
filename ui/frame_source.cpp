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
    // Keep the cache under ~512 MiB whatever the frame size.
    size_t bytes = static_cast<size_t>(m_width) * m_height * 4;
    m_capacity = std::clamp<size_t>((512u << 20) / std::max<size_t>(bytes, 1), 2, 1024);
}

Image FrameSource::linear(int index) {
    index = std::clamp(index, 0, m_frames - 1);
    return m_project ? m_project->read_frame(index) : m_clip->read(index);
}

const std::vector<unsigned char>& FrameSource::rgba8(int index) {
    index = std::clamp(index, 0, m_frames - 1);
    auto it = m_cache.find(index);
    if (it != m_cache.end()) {
        m_lru.remove(index);
        m_lru.push_front(index);
        return it->second;
    }
    Image img = linear(index);
    std::vector<unsigned char> px(static_cast<size_t>(img.width) * img.height * 4);
    for (size_t i = 0, n = static_cast<size_t>(img.width) * img.height; i < n; ++i) {
        for (int c = 0; c < 3; ++c) px[4 * i + c] = linear_to_srgb8(img.pixels[3 * i + c]);
        px[4 * i + 3] = 255;
    }
    if (m_cache.size() >= m_capacity && !m_lru.empty()) {
        m_cache.erase(m_lru.back());
        m_lru.pop_back();
    }
    m_lru.push_front(index);
    return m_cache[index] = std::move(px);
}

}  // namespace refocus
